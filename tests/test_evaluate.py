"""``twinslam evaluate`` (issue #19): the live nodes per scenario × policy × seed, every run a
CSV row, mean ± CI per scenario and policy as CSV, markdown and plot; bad requests refused
before the first run."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from twinslam.cli.main import main


def test_evaluate_runs_every_seed_and_summarises(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "live"
    # 181 frames forward then back: 361 played, 6 full slots; the lens covered for 3 s from
    # played frame 252, uncovered at 342 (inside the last full slot)
    code = main(["evaluate", "--sequence", "synthetic:181", "--frames", "181", "--policy", "lff",
                 "--scenario", "revisit-lost", "--seeds", "2", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    with (out / "runs.csv").open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["scenario"], r["policy"], r["seed"]) for r in rows] == [
        ("revisit-lost", "lff", "0"), ("revisit-lost", "lff", "1")]
    for r in rows:
        assert int(r["slots"]) == 6 and int(r["untracked_frames"]) >= 90, r
        assert int(r["tracking_failures"]) == 1, "the covered lens lost no frame"
        assert 2.9 < float(r["recover_s"]) < 3.5, "tracking did not come back after the cover"
        assert float(r["ate_m"]) < 0.3      # the 90 covered frames keep the last pose
    with (out / "summary.csv").open(encoding="utf-8") as fh:
        summary = list(csv.DictReader(fh))
    assert len(summary) == 1 and summary[0]["runs"] == "2"
    ates = [float(r["ate_m"]) for r in rows]
    assert float(summary[0]["ate_m_mean"]) == pytest.approx(sum(ates) / 2)
    assert "| revisit-lost | lff | 2 |" in (out / "summary.md").read_text(encoding="utf-8")
    assert (out / "summary.png").stat().st_size > 10_000
    assert "[2/2] revisit-lost" in text


@pytest.mark.parametrize(("args", "why"), [
    (["--scenario", "sideways"], "unknown scenario 'sideways'"),
    (["--policy", "mbrl:/nonexistent.pt"], "no such policy checkpoint"),
    (["--seeds", "0"], "--seeds must be >= 1"),
    (["--sequence", "/nonexistent/folder"], "does not exist"),
])
def test_evaluate_refuses_a_bad_request_before_running(
        args: list[str], why: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["evaluate", "--sequence", "synthetic:30", "--out", str(tmp_path / "o"),
                 *args])
    assert code == 2 and why in capsys.readouterr().err
    assert not (tmp_path / "o").exists(), "nothing may run (or be written) for a bad request"
