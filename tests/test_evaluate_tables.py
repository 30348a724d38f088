"""The live evaluation's tables on hand-made runs: policy labels and variants, the per-label
summary (a variant's training runs pooled), and the paired comparison with the best rule
policy seed by seed."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import pytest

from twinslam.live.report import RunReport
from twinslam.live.runs import RunKey, RunResult, RunTask, policy_variants
from twinslam.live.scenarios import SCENARIOS
from twinslam.live.tables import paired_differences, paired_markdown, side_by_side, summarise


def _run(policy: str, seed: int, failures: int, ate: float, spec: str = "") -> RunResult:
    report = RunReport(spec or policy, 10, -500.0, 0.1, -550.0, ate, 0.1, 20, 2_000_000, 40.0,
                       3 * failures, failures, 1, 0.5, 80.0, 30.0)
    return RunResult(RunKey("revisit-v15", "edge", policy, seed, spec), report, None, None)


def _tasks(policy: str, seeds: int, spec: str = "") -> list[RunTask]:
    """``seeds`` runs of ``policy`` on the revisit scenario, as a sweep hands them out (the
    tests replace the run itself)."""
    return [RunTask(RunKey("revisit", "edge", policy, seed, spec), "synthetic", 10,
                    SCENARIOS["revisit"], Path("p.yaml"), 10.0, None) for seed in range(seeds)]


def test_policy_items_become_labels_and_edge_policies() -> None:
    assert policy_variants("lff, mbrl:results/amm_s0.pt,AMM=mbrl:a.pt,AMM=mbrl:b.pt") == [
        ("lff", "lff"), ("mbrl:amm_s0", "mbrl:results/amm_s0.pt"), ("AMM", "mbrl:a.pt"),
        ("AMM", "mbrl:b.pt")]
    with pytest.raises(ValueError, match="LABEL=POLICY"):
        policy_variants("AMM=")


def test_paired_differences_take_the_best_rule_policy_seed_by_seed() -> None:
    results = []
    for seed in range(4):
        results += [_run("lff", seed, 10 + seed, 0.20), _run("adapt", seed, 20 + seed, 0.30),
                    # two training runs of one variant: 2 and 4 fewer failures than LFF
                    _run("AMM", seed, 8 + seed, 0.25, "mbrl:a.pt"),
                    _run("AMM", seed, 6 + seed, 0.15, "mbrl:b.pt")]
    rows = {(r.metric, r.policy): r for r in paired_differences(results)}
    fails = rows[("tracking_failures", "AMM")]
    assert fails.best == "lff" and fails.seeds == 4
    assert fails.difference == pytest.approx(-3.0) and fails.ci95 == pytest.approx(0.0)
    assert rows[("tracking_failures", "adapt")].difference == pytest.approx(10.0)
    assert ("tracking_failures", "lff") not in rows, "the best is not compared with itself"
    ate = rows[("ate_m", "AMM")]
    assert ate.best == "lff" and ate.difference == pytest.approx(0.0)
    # the calibration's share is unknown without a dataset: not compared
    assert ("device_failure_share", "AMM") not in rows
    assert ("| revisit-v15 | edge | tracking_failures | lff | AMM | 4 | -3.0 ± 0.0 (CI excludes "
            "0) |") in paired_markdown([fails])

    summary = {r.policy: r for r in summarise(results)}
    assert summary["AMM"].runs == 8, "a variant pools its training runs"
    mean, half = summary["AMM"].figures["tracking_failures"]
    assert mean == pytest.approx(8.5) and half > 0
    assert math.isnan(summary["lff"].figures["device_failure_share"][0])


def test_a_failed_run_is_reported_and_the_others_go_on(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from twinslam.live import runs as evaluate

    def fake(task: evaluate.RunTask) -> RunResult:
        if task.key.seed == 1:
            raise RuntimeError("edge_mapper exited during the run: boom")
        return _run(task.key.policy, task.key.seed, 3, 0.1)

    monkeypatch.setattr(evaluate, "run_one", fake)
    tasks = _tasks("lff", 3)
    lines: list[str] = []
    results, failures = evaluate.run_all(tasks, tmp_path, echo=lines.append)
    assert [r.key.seed for r in results] == [0, 2]
    assert [f.key.seed for f in failures] == [1] and "boom" in failures[0].error
    assert any("FAILED" in line and "seed 1" in line and "boom" in line for line in lines)
    assert "RuntimeError: edge_mapper exited" in (tmp_path / "failures.txt").read_text()
    assert len((tmp_path / "runs.csv").read_text().splitlines()) == 3   # header + 2 runs


def test_an_interrupted_evaluation_resumes_with_what_it_measured(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from twinslam.live import runs as evaluate

    ran: list[int] = []

    def fake(task: evaluate.RunTask) -> RunResult:
        ran.append(task.key.seed)
        run = _run(task.key.policy, task.key.seed, task.key.seed + 2, 0.1 * task.key.seed,
                   task.key.spec)
        return RunResult(task.key, run.report, None, None)

    monkeypatch.setattr(evaluate, "run_one", fake)
    # a label over a checkpoint: runs.csv then has two policy columns, "AMM" and the spec
    tasks = _tasks("AMM", 4, "mbrl:a.pt")
    first, _ = evaluate.run_all(tasks[:2], tmp_path, echo=lambda _: None)
    lines: list[str] = []
    results, failures = evaluate.run_all(tasks, tmp_path, echo=lines.append,
                                         resume=True)
    assert ran == [0, 1, 2, 3] and not failures          # seeds 0, 1 not run again
    assert "resuming: 2 of 4 runs" in lines[0]
    assert [r.key for r in results] == [t.key for t in tasks]
    # read back exactly (repr: a NaN figure reads back as NaN, which == does not see)
    assert [repr(r.report) for r in results[:2]] == [repr(r.report) for r in first]
    assert len((tmp_path / "runs.csv").read_text().splitlines()) == 5   # one header, 4 runs
    summary = summarise(results)[0]
    assert summary.runs == 4
    assert summary.figures["tracking_failures"][0] == pytest.approx(3.5)


def test_resuming_runs_made_under_other_settings_is_refused_and_loses_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two runs finished at half the camera rate; the evaluation resumed at full rate (or with
    its parameter file edited) would put runs of two settings under one key in one table:
    refused before anything runs or is written, the setting named. Resumed as it was made,
    it runs the missing seeds only."""
    import dataclasses

    from twinslam.live import runs as evaluate

    ran: list[int] = []

    def fake(task: evaluate.RunTask) -> RunResult:
        ran.append(task.key.seed)
        return RunResult(task.key, _run(task.key.policy, task.key.seed, 3, 0.1).report, None,
                         None)

    monkeypatch.setattr(evaluate, "run_one", fake)
    params = tmp_path / "params.yaml"
    params.write_text("edge_mapper:\n  ros__parameters:\n    vmax: 45\n")
    out = tmp_path / "out"
    slow = [dataclasses.replace(t, rate=0.5, params=params) for t in _tasks("lff", 4)]
    evaluate.run_all(slow[:2], out, echo=lambda _: None)
    before = (out / "runs.csv").read_text()
    full = [dataclasses.replace(t, rate=1.0) for t in slow]
    with pytest.raises(ValueError, match=r"rate 0\.5 there, 1\.0 now.*new --out folder"):
        evaluate.run_all(full, out, echo=lambda _: None, resume=True)
    params.write_text("edge_mapper:\n  ros__parameters:\n    vmax: 20\n")
    with pytest.raises(ValueError, match="params_sha256"):
        evaluate.run_all(slow, out, echo=lambda _: None, resume=True)
    assert ran == [0, 1] and (out / "runs.csv").read_text() == before
    params.write_text("edge_mapper:\n  ros__parameters:\n    vmax: 45\n")
    # the same file named by another path is the same setting
    renamed = [dataclasses.replace(t, params=tmp_path / ".." / tmp_path.name / "params.yaml")
               for t in slow]
    results, failures = evaluate.run_all(renamed, out, echo=lambda _: None, resume=True)
    assert ran == [0, 1, 2, 3] and not failures and len(results) == 4


def test_paced_runs_are_another_setting_and_a_folder_made_before_pacing_was_real_time(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--pace`` changes what a run measures (a device that sees every frame): a resume with
    another pace is refused; a folder whose settings predate the option was played in real
    time, and resumes as such."""
    import dataclasses
    import json

    from twinslam.live import runs as evaluate

    def fake(task: evaluate.RunTask) -> RunResult:
        return RunResult(task.key, _run(task.key.policy, task.key.seed, 3, 0.1).report, None,
                         None)

    monkeypatch.setattr(evaluate, "run_one", fake)
    out = tmp_path / "out"
    tasks = _tasks("lff", 3)
    evaluate.run_all(tasks[:2], out, echo=lambda _: None)
    paced = [dataclasses.replace(t, pace_frames=30) for t in tasks]
    with pytest.raises(ValueError, match=r"pace_frames 0 there, 30 now"):
        evaluate.run_all(paced, out, echo=lambda _: None, resume=True)
    settings = out / evaluate.SETTINGS_FILE
    older = {run: {k: v for k, v in kept.items() if k != "pace_frames"}
             for run, kept in json.loads(settings.read_text()).items()}
    settings.write_text(json.dumps(older))
    with pytest.raises(ValueError, match=r"pace_frames 0 there, 30 now"):
        evaluate.run_all(paced, out, echo=lambda _: None, resume=True)
    results, failures = evaluate.run_all(tasks, out, echo=lambda _: None, resume=True)
    assert not failures and len(results) == 3


def test_a_folder_of_an_older_version_resumes_with_the_later_columns_not_measured(
        tmp_path: Path) -> None:
    """runs.csv written before the columns added since (``jumps``, the losses' shares and
    durations): its runs read back with those NaN (not measured), and the file is rewritten
    with today's columns before new rows append."""
    from twinslam.live import runs as evaluate

    header, added = evaluate.RUNS_HEADER, list(evaluate.ADDED_COLUMNS)
    assert header[-len(added):] == added
    done = _run("lff", 0, 2, 0.1, "lff")
    values = [*asdict(done.key).values(), *asdict(done.report).values()]
    row = [str(v) for v in values[:-len(added)]]
    (tmp_path / "runs.csv").write_text(",".join(header[:-len(added)]) + "\n" + ",".join(row)
                                       + "\n")
    (back,) = evaluate.finished_runs(tmp_path).values()
    assert all(math.isnan(getattr(back.report, c)) for c in added)
    kept = [f for f in asdict(done.report) if f not in added]
    assert [getattr(back.report, f) for f in kept] == [getattr(done.report, f) for f in kept]
    assert (tmp_path / "runs.csv").read_text().splitlines()[0] == ",".join(header)


def test_resumed_frames_of_an_older_version_gain_the_archive_columns_unmeasured(
        tmp_path: Path) -> None:
    """calibration_frames.csv written before the archive's reach and the failure cause were:
    resuming rewrites it with today's header, its rows' new cells not measured, so that the
    runs still to do append aligned rows; a file of another layout is refused."""
    from twinslam.live import runs as evaluate

    header, added = evaluate.FRAMES_HEADER, list(evaluate.ADDED_FRAME_COLUMNS)
    assert header[-len(added):] == added
    old_row = ["revisit-v15", "edge", "lff", "0", "", *["1"] * (len(header) - len(added) - 5)]
    frames = tmp_path / "calibration_frames.csv"
    frames.write_text(",".join(header[:-len(added)]) + "\n" + ",".join(old_row) + "\n")
    evaluate.run_all([], tmp_path, resume=True)
    lines = frames.read_text().splitlines()
    assert lines == [",".join(header), ",".join([*old_row, "nan", ""])]
    frames.write_text("scenario,slot\nrevisit,1\n")
    with pytest.raises(ValueError, match="another version"):
        evaluate.run_all([], tmp_path, resume=True)


def test_resuming_into_a_folder_of_another_version_is_refused(tmp_path: Path) -> None:
    from twinslam.live import runs as evaluate

    (tmp_path / "runs.csv").write_text("scenario,policy,seed\nrevisit,lff,0\n")
    with pytest.raises(ValueError, match="another version"):
        evaluate.finished_runs(tmp_path)


def test_the_summary_table_shows_shares_to_a_tenth_of_a_percent() -> None:
    from twinslam.live.tables import METRICS, SummaryRow, markdown_table

    figures = {m: (1.0, 0.5) for m, _, _ in METRICS}
    figures["device_failure_share"] = (0.2345, 0.0412)
    figures["predicted_lost_share"] = (0.0071, math.nan)
    table = markdown_table([SummaryRow("revisit-v15", "edge", "lff", 10, figures)])
    assert "| 0.234 ± 0.041 | 0.007 |" in table


def test_runs_whose_device_dropped_camera_frames_are_flagged(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
        ) -> None:
    """A device that fell behind its camera (a machine short of CPU) is said to have done so
    on the run's progress line, below the summary table and at the end of the evaluation; an
    evaluation none of whose devices dropped a frame says nothing of it."""
    import dataclasses

    from twinslam.cli.commands import evaluate as command
    from twinslam.live import runs as evaluate
    from twinslam.live.tables import dropped_frames_note, summarise, write_summary

    def fake(task: evaluate.RunTask) -> RunResult:
        run = _run(task.key.policy, task.key.seed, 3, 0.1)
        return dataclasses.replace(run, report=dataclasses.replace(
            run.report, frames_dropped=75 if task.key.seed == 1 else 0))

    monkeypatch.setattr(evaluate, "run_one", fake)
    tasks = _tasks("lff", 3)
    lines: list[str] = []
    results, _ = evaluate.run_all(tasks, tmp_path, echo=lines.append)
    flagged = [line for line in lines if "DROPPED" in line]
    assert len(flagged) == 1 and "seed 1" in flagged[0] and "DROPPED 75 camera frames" \
        in flagged[0]
    note = dropped_frames_note(results)
    assert note is not None and note.startswith("1 of 3 runs dropped camera frames")
    assert "revisit-v15 edge lff seed 1: 75" in note and "seed 0" not in note
    write_summary(summarise(results), tmp_path, note)
    assert f"**Warning.** {note}" in (tmp_path / "summary.md").read_text(encoding="utf-8")
    command._print_tables(results, tmp_path)
    assert capsys.readouterr().err.strip() == f"warning: {note}"

    clean = [r for r in results if r.report.frames_dropped == 0]
    assert dropped_frames_note(clean) is None
    command._print_tables(clean, tmp_path)
    assert "Warning" not in (tmp_path / "summary.md").read_text(encoding="utf-8")
    assert capsys.readouterr().err == ""


def test_the_side_by_side_table_flags_a_run_whose_device_dropped_camera_frames() -> None:
    calm, busy = _run("lff", 0, 3, 0.2), _run("pu", 0, 3, 0.2)
    busy.report.frames_dropped = 75
    header, *rows = side_by_side([calm])
    assert header.split()[-1] == "dropped" and rows[0].split()[-1] == "0" and len(rows) == 1
    lines = side_by_side([calm, busy])
    assert lines[2].split()[-1] == "75!"
    assert lines[3].startswith("! 1 of 2 runs dropped camera frames")
    assert "pu seed 0: 75" in lines[3]


def test_the_summaries_say_which_runs_played_frames_the_player_skipped(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A sequence with an unreadable image: the player skips it, and make run's table and
    evaluate's summary say so apart from frames a busy device dropped."""
    from twinslam.cli.commands import evaluate as command

    clean, corrupt = _run("lff", 0, 3, 0.2), _run("pu", 0, 3, 0.2)
    corrupt.report.frames_skipped = 2
    assert len(side_by_side([clean])) == 2                      # nothing to say: no note
    note = side_by_side([clean, corrupt])[-1]
    assert note.startswith("! 1 of 2 runs played a sequence with unreadable frames")
    assert "pu seed 0: 2" in note and "dropped" not in note
    command._print_tables([clean, corrupt], tmp_path)
    assert "unreadable frames" in (tmp_path / "summary.md").read_text(encoding="utf-8")
    assert "runs played a sequence with unreadable frames" in capsys.readouterr().err


def test_the_side_by_side_table_names_each_runs_device_and_its_restores() -> None:
    """make run's rows of one policy with two devices: which device each row ran (``-`` where
    the run names none) and how many keyframes its edge brought back."""
    plain, default = _run("lff", 0, 3, 0.2), _run("lff", 0, 1, 0.1)
    default.variant, default.report.restores = "default", 16.0
    header, *rows = side_by_side([plain, default])
    column = header.split().index("device") - 1      # "map source" is two words, "device" one
    restores = header.split().index("restor") - 1
    assert [r.split()[column] for r in rows] == ["-", "default"]
    assert [r.split()[restores] for r in rows] == ["nan", "16"]


def test_a_device_whose_keyframes_never_moved_reads_its_anchored_figures_as_published() -> None:
    """Anchored to keyframes that never moved, a pose is where it was published: a runs.csv
    written before the anchored columns reads them as the published ones (a column it has
    is kept), and a run that closed a loop — whose keyframes moved — is refused."""
    from twinslam.live.runs import anchored_as_published

    old = [{"seed": "0", "ate_m": "0.05", "revisit_error_m": "0.04", "loops_closed": "0"}]
    (row,) = anchored_as_published(old, "before")
    assert (row["anchored_ate_m"], row["anchored_revisit_error_m"]) == ("0.05", "0.04")
    newer = [{**old[0], "anchored_ate_m": "0.03"}]
    assert anchored_as_published(newer, "x")[0]["anchored_ate_m"] == "0.03"
    with pytest.raises(ValueError, match="looped: its runs closed loops"):
        anchored_as_published([{**old[0], "loops_closed": "7.0"}], "looped")
