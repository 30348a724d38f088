"""Sweeps of live runs (``twinslam evaluate``): the live system as the judge of map
management.

Runs the nodes — player, device, edge — as processes on a private loopback domain, once per
scenario × device map source × policy × seed (the seed drives the uplink's channel model, and
the walk when the sequence is the synthetic room), and reports what a user of the device would
see: ATE and RPE against ground truth (evo), tracking failures, relocalisations and time to
recover, the edge's υ and lost share, uploads and edge milliseconds per slot. Every run is a
row of ``runs.csv`` (written as it finishes, so an interrupted evaluation keeps what it
measured); ``summary.csv`` and ``summary.md`` hold mean ± 95 % CI over the seeds per scenario
× map source × policy, ``summary.png`` plots them.

Each run is also a calibration of the simulator against the device
(:mod:`twinslam.live.calibration.frames`): ``calibration.csv`` has, per run, the share of
next-slot frames the simulator's rule calls lost beside the share the device failed, the
precision and recall of "lost" for "device failure", and Spearman's ρ of u with the device's
translation error and inlier count; ``calibration_frames.csv`` has every frame. Runs go to
``--jobs`` worker processes or as Ray tasks (``--executor ray``), each on a loopback domain
of its own.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import time
import traceback
from collections.abc import Callable, Collection, Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

from twinslam.covisibility.dataset import load_covisibility
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.calibration.frames import LiveFrames, live_frames, played_frames
from twinslam.live.calibration.prediction import Calibration, calibrate, failure_cause
from twinslam.live.launcher import LaunchConfig, Launcher
from twinslam.live.node_logs import write_logs
from twinslam.live.report import RunReport, policy_label
from twinslam.live.run_picture import plot_run
from twinslam.live.scenarios import Scenario
from twinslam.policies.registry import LEARNED_PREFIX, POLICY_KINDS
from twinslam.reporting import file_name, write_csv
from twinslam.sequences.opening import is_synthetic, synthetic_walk
from twinslam.slot_protocol.lost_frame_rule import MIN_SHARED_POINTS
from twinslam.sweeps import Executor, LocalExecutor


@dataclass(frozen=True)
class RunKey:
    scenario: str
    map_source: str
    policy: str              #: the label tables group by: several training runs may share one
    seed: int
    spec: str = ""           #: the edge's policy (``mbrl:CHECKPOINT``); "" when the label is it

    @property
    def edge_policy(self) -> str:
        return self.spec or self.policy

    @property
    def file_stem(self) -> str:
        """The run as a file name: scenario, map source, policy (a checkpoint by its name),
        seed."""
        path = self.edge_policy.partition(":")[2]
        policy = f"{self.policy}-{Path(path).stem}" if path and self.spec else self.policy
        return file_name(f"{self.scenario}_{self.map_source}_{policy}_s{self.seed}")


def policy_variants(text: str) -> list[tuple[str, str]]:
    """``--policy`` items as (label, edge policy): ``LABEL=POLICY`` or ``POLICY`` (labelled
    ``mbrl:<checkpoint name>`` for a learned one); a label given to several checkpoints pools
    their training runs in every table. ``mpc:H=2`` is a policy with options, not a label: a
    label has no ``:``, and what follows its ``=`` names a policy (``planner=mpc:H=2``)."""
    out = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        label, sep, spec = item.partition("=")
        if sep and ":" in label and spec.partition(":")[0].strip() not in POLICY_KINDS:
            sep = ""                         # an option's '=' (mpc:H=2), not a label's
        if not sep:
            label, spec = policy_label(item), item
        if not label.strip() or not spec.strip():
            raise ValueError(f"--policy {item!r}: use POLICY or LABEL=POLICY")
        out.append((label.strip(), spec.strip()))
    return out


@dataclass(frozen=True)
class RunTask:
    """One live run as a worker process receives it."""

    key: RunKey
    sequence: str            #: as the player opens it (a synthetic walk carries its seed)
    frames: int
    scenario: Scenario
    params: Path
    timeout_s: float
    covis: Path | None       #: the played frames' covisibility, for the calibration
    verbose: bool = False    #: print every slot's status line
    start: int = 0           #: the sequence's first frame played
    #: where the run's PNG goes (run_picture), its nodes' logs beside it (.log); None: neither
    picture: Path | None = None
    #: edge parameters over the parameter file's (``name:=value``), and what the tables call
    #: this run's device and edge ("": none, one device in the table)
    edge_params: tuple[str, ...] = ()
    variant: str = ""
    rate: float = 1.0        #: the cameras' speed, x the recorded frame rate
    #: the camera waits for its device beyond this many unposed frames (0: real time;
    #: :mod:`twinslam.sequence_player.pacing`)
    pace_frames: int = 0


@dataclass
class RunResult:
    key: RunKey
    report: RunReport
    frames: LiveFrames | None     #: None without a covisibility dataset
    calibration: Calibration | None
    variant: str = ""        #: the task's


def sequence_for(sequence: str, seed: int) -> str:
    """A synthetic world is walked on a seed's own path; a recorded sequence is what it is."""
    return synthetic_walk(sequence, seed) if is_synthetic(sequence) else sequence


def run_one(task: RunTask) -> RunResult:
    """Play one run on a loopback domain of its own; calibrate it when a dataset is given.

    A learned policy's run also starts the twin node with the policy's checkpoint, so the
    policy decides on the twin's latents (``/udt/rate_latent``) as on a deployed edge; without
    it a twin-driven policy would hand every slot to the edge's fallback policy."""
    key = task.key
    extra = {"device_tracker": [f"seed:={key.seed}", f"map_source:={key.map_source}"],
             "edge_mapper": list(task.edge_params)}
    kind, _, checkpoint = key.edge_policy.partition(":")
    learned = kind == LEARNED_PREFIX and bool(checkpoint)
    if learned:
        extra["udt_node"] = [f"policy_checkpoint:={checkpoint}"]
    config = LaunchConfig(task.sequence, key.edge_policy, task.frames, task.rate, task.params,
                          timeout_s=task.timeout_s, scenario=task.scenario, extra=extra,
                          start=task.start, with_twin=learned, pace_frames=task.pace_frames)
    with LoopbackDomain() as dom:
        dom.activate()
        launcher = Launcher(dom, config, print if task.verbose else None)
        report = launcher.run()
    if task.picture is not None:
        write_logs(launcher.logs, task.picture.with_suffix(".log"))
    if task.picture is not None and launcher.record is not None:
        plot_run(launcher.record, f"{key.policy}, {key.map_source} device, {key.scenario}, "
                 f"seed {key.seed}: {report.tracking_failures} failures, ATE "
                 f"{report.ate_m:.3f} m", task.picture)
    if task.covis is None or launcher.record is None:
        return RunResult(key, report, None, None, task.variant)
    dataset = load_covisibility(task.covis)
    played = played_frames(task.sequence, task.frames, task.scenario, dataset,
                           rate=task.rate, start=task.start)
    frames = live_frames(launcher.record, dataset, played)
    return RunResult(key, report, frames,
                     calibrate((f.calibration for f in frames.frames), MIN_SHARED_POINTS),
                     task.variant)


RUNS_HEADER = [f.name for f in fields(RunKey)] + [f.name for f in fields(RunReport)]
CALIBRATION_HEADER = [f.name for f in fields(RunKey)] + [
    "min_shared", "startup_frames", "unplaced_frames", *[f.name for f in fields(Calibration)]]
FRAMES_HEADER = [f.name for f in fields(RunKey)] + [
    "slot", "position", "frame_id", "row", "map_version", "shared_points", "covisibility",
    "uncertainty", "shared_points_tracked_map", "covisibility_tracked_map",
    "uncertainty_tracked_map", "device_tracked", "inliers", "translation_error_m",
    "shared_points_archive", "failure_cause"]


def _append(path: Path, rows: list[list[object]]) -> None:
    with path.open("a", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(rows)


def _write_result(out: Path, result: RunResult) -> None:
    key = [*asdict(result.key).values()]
    _append(out / "runs.csv", [[*key, *asdict(result.report).values()]])
    if result.frames is None or result.calibration is None:
        return
    _append(out / "calibration.csv", [[*key, MIN_SHARED_POINTS, result.frames.startup,
                                       result.frames.unplaced,
                                       *result.calibration.fields.values()]])
    _append(out / "calibration_frames.csv", [
        [*key, f.slot, f.position, f.frame_id, f.row, f.map_version,
         f.calibration.prediction.shared_points, f.calibration.prediction.covisibility,
         f.calibration.prediction.uncertainty, f.on_tracked_map.shared_points,
         f.on_tracked_map.covisibility, f.on_tracked_map.uncertainty,
         int(f.calibration.device_tracked), f.calibration.inliers,
         f.calibration.translation_error_m, f.archive_shared_points,
         "" if f.calibration.device_tracked else failure_cause(
             f.on_tracked_map.shared_points, f.archive_shared_points, MIN_SHARED_POINTS)]
        for f in result.frames.frames])


#: each finished run's settings that its key does not hold (``run_settings``), by run
SETTINGS_FILE = "run_settings.json"


def _key_text(key: RunKey) -> str:
    return "|".join(str(v) for v in asdict(key).values())


def run_settings(task: RunTask) -> dict[str, object]:
    """What shapes ``task``'s run beside its key: the frames played, the cameras' rate, the
    parameter file (its path and a digest of what it says) and the edge's overrides. Two
    runs of one key made under other settings are two measurements, not one."""
    try:
        digest = hashlib.sha256(task.params.read_bytes()).hexdigest()[:16]
    except OSError:
        digest = ""                       # checked before the runs start (params_file_problem)
    # a folder by its absolute path (the same data named relatively or not is the same run);
    # a synthetic walk's spec as it is
    sequence = str(Path(task.sequence).resolve()) if Path(task.sequence).exists() \
        else task.sequence
    return {"sequence": sequence, "frames": task.frames, "start": task.start,
            "rate": task.rate, "pace_frames": task.pace_frames, "params": str(task.params),
            "params_sha256": digest, "edge_params": list(task.edge_params)}


#: a setting a folder's record may lack (made before it existed): the value it was made with
_SETTING_BEFORE_IT_EXISTED: dict[str, object] = {"pace_frames": 0}


def settings_mismatch(out: Path, recorded: Mapping[str, Mapping[str, object]],
                      tasks: list[RunTask], finished: Collection[RunKey]) -> str:
    """Why the runs of ``finished`` (read back from ``out``, their settings ``recorded`` there)
    cannot stand beside ``tasks``: one was made under other settings (:func:`run_settings`;
    the first differences named); "" when none was, or when the folder predates the record
    (nothing to compare)."""
    problems = []
    for task in tasks:
        then = recorded.get(_key_text(task.key))
        if task.key not in finished or then is None:
            continue
        now = run_settings(task)
        # the parameter file is compared by what it says: the same file named another way
        # (relative, absolute) is the same run
        changed = [f"{name} {was!r} there, {value!r} now" for name, value in now.items()
                   if name != "params" and (was := then.get(
                       name, _SETTING_BEFORE_IT_EXISTED.get(name))) != value]
        if changed:
            problems.append(f"{task.key.file_stem}: {'; '.join(changed)}")
    if not problems:
        return ""
    more = f" (and {len(problems) - 1} more runs)" if len(problems) > 1 else ""
    return (f"{out} holds runs made under other settings — {problems[0]}{more}; resume "
            "with the settings they were made under, or into a new --out folder")


def _read_settings(out: Path) -> dict[str, dict[str, object]]:
    path = out / SETTINGS_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} is unreadable ({exc}); resume into a new --out folder"
                         ) from exc
    return data if isinstance(data, dict) else {}


def _record_settings(out: Path, settings: dict[str, dict[str, object]]) -> None:
    """Write the runs' settings whole, then move them over the file (a run interrupted
    mid-write leaves the last complete record)."""
    path = out / SETTINGS_FILE
    part = path.with_suffix(".json.part")
    part.write_text(json.dumps(settings, indent=1, sort_keys=True), encoding="utf-8")
    os.replace(part, path)


def _line(i: int, total: int, r: RunResult, started: float, resumed: int = 0) -> str:
    elapsed = time.monotonic() - started
    eta = elapsed / max(i - resumed, 1) * (total - i)
    rep, cal = r.report, r.calibration
    side = (f", predicted lost {cal.predicted_lost_share:.1%} vs device failed "
            f"{cal.device_failure_share:.1%}" if cal is not None else "")
    dropped = (f", DROPPED {rep.frames_dropped} camera frames (short of CPU)"
               if rep.frames_dropped else "")
    if rep.frames_skipped > 0:
        dropped += f", {rep.frames_skipped:.0f} unreadable frames skipped by the player"
    return (f"[{i}/{total}] {r.key.scenario:<13} {r.key.map_source:<10} {rep.label:<14} seed "
            f"{r.key.seed}: ATE {rep.ate_m:.3f} m, {rep.tracking_failures} failures, "
            f"{rep.relocalisations} relocalisations, υ {rep.mean_uncertainty:.1f}{side}"
            f"{dropped} ({elapsed / 60:.1f} min, ~{eta / 60:.1f} min left)")


@dataclass
class RunFailure:
    """A run that raised: its key and the traceback, reported while the others go on."""

    key: RunKey
    error: str


def run_or_fail(task: RunTask) -> RunResult | RunFailure:
    """:func:`run_one`, an exception returned as a :class:`RunFailure` instead of raised."""
    try:
        return run_one(task)
    except Exception:                 # any run may fail; the sweep reports it and goes on
        return RunFailure(task.key, traceback.format_exc())


#: how a runs.csv / calibration.csv cell is read back, by the dataclass field's annotation
#: a dataclass read back from a CSV row
D = TypeVar("D", bound="DataclassInstance")

_CELL = {"int": int, "float": float, "str": str}


#: columns a later version added at the end of runs.csv, and what the rows of an older file
#: read for them: not measured then
ADDED_COLUMNS = {"jumps": "nan", "failed_share": "nan", "loss_p95_s": "nan",
                 "longest_loss_s": "nan", "device_cpu_ms": "nan", "downlink_mb": "nan",
                 "restores": "nan", "max_error_m": "nan", "jitter_rms_mm": "nan",
                 "jitter_median_mm": "nan", "jitter_p95_mm": "nan", "jitter_over_20mm": "nan",
                 "truth_jitter_rms_mm": "nan", "poses_refused": "nan",
                 "keyframes_refused": "nan", "longest_no_upload_slots": "nan",
                 "frames_skipped": "nan", "revisit_error_m": "nan", "revisit_pairs": "nan",
                 "odom_jitter_rms_mm": "nan", "odom_step_excess_mm": "nan",
                 "pnp_ransac_share": "nan", "loops_closed": "nan", "loop_closing_ms": "nan",
                 "outlier_share": "nan", "loops_refused": "nan", "duplicate_share": "nan",
                 "anchored_revisit_error_m": "nan", "anchored_ate_m": "nan",
                 "keyframes_missing": "nan", "map_in_pieces_slots": "nan"}
#: the same for calibration_frames.csv
ADDED_FRAME_COLUMNS = {"shared_points_archive": "nan", "failure_cause": ""}
#: each anchored figure of a run → the published one it equals when the run's keyframes never
#: moved once in the map (no loop closed, no bundle adjustment)
ANCHORED_AS_PUBLISHED = {"anchored_ate_m": "ate_m", "anchored_revisit_error_m": "revisit_error_m"}


def anchored_as_published(rows: list[dict[str, str]], where: object) -> list[dict[str, str]]:
    """runs.csv rows of a device whose keyframes never moved, each anchored figure the file
    predates read as its published one; ValueError (naming ``where``) if a run closed a loop,
    whose keyframes did move."""
    if any(float(r.get("loops_closed") or 0) > 0 for r in rows):
        raise ValueError(f"{where}: its runs closed loops; their keyframes moved")
    return [{**r, **{anchored: r[published] for anchored, published
                     in ANCHORED_AS_PUBLISHED.items() if anchored not in r and published in r}}
            for r in rows]


def _read_rows(path: Path, header: list[str], added: dict[str, str] = ADDED_COLUMNS
               ) -> list[list[str]]:
    """The rows of one of the tables :func:`run_all` writes, by position: runs.csv has two
    ``policy`` columns (the label and the report's). A file written before the columns of
    ``added`` existed is rewritten with them (its rows unchanged, the new cells what ``added``
    says: not measured), so that the runs still to do append rows of today's columns."""
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    old = rows[0] if rows else []
    missing = header[len(old):]
    if not rows or header[:len(old)] != old or any(c not in added for c in missing):
        raise ValueError(f"{path} was written by another version of twinslam evaluate "
                         f"(its columns differ); resume into a new --out folder")
    body = [row + [added[c] for c in missing] for row in rows[1:]]
    if missing:
        write_csv(path, header, body)
    return body


def _typed(cls: type[D], cells: list[str]) -> D:
    """A dataclass from its fields' cells, in field order."""
    return cls(*(_CELL[str(f.type)](c) for f, c in zip(fields(cls), cells, strict=True)))


def finished_runs(out: Path) -> dict[RunKey, RunResult]:
    """The runs an earlier evaluation into ``out`` finished, by key (``runs.csv`` and
    ``calibration.csv``; the frames stay in ``calibration_frames.csv``): an evaluation that
    was interrupted after an hour resumes where it stopped instead of starting over."""
    if not (out / "runs.csv").is_file():
        return {}
    n_key = len(fields(RunKey))
    calibrations = {}
    if (out / "calibration.csv").is_file():
        skip = len(CALIBRATION_HEADER) - len(fields(Calibration))   # min_shared, startup, ..
        for row in _read_rows(out / "calibration.csv", CALIBRATION_HEADER):
            calibrations[_typed(RunKey, row[:n_key])] = _typed(Calibration, row[skip:])
    finished = {}
    for row in _read_rows(out / "runs.csv", RUNS_HEADER):
        key = _typed(RunKey, row[:n_key])
        finished[key] = RunResult(key, _typed(RunReport, row[n_key:]), None,
                                  calibrations.get(key))
    return finished


def run_all(tasks: list[RunTask], out: Path, executor: Executor | None = None,
            echo: Callable[[str], None] = print,
            resume: bool = False) -> tuple[list[RunResult], list[RunFailure]]:
    """Every task on ``executor`` (local worker processes or Ray; None: in this process, one
    after the other); each result's rows appended as it lands, a failed run reported (its
    traceback in ``failures.txt``) while the rest go on. With ``resume``, the runs ``out``
    already holds are read back instead of run again (a failed one is tried again); a
    folder whose runs were made under other settings than the tasks' (:func:`run_settings`:
    another rate, frames, parameter file) is refused before anything is written, ValueError.
    The results in task order, and the failures."""
    out.mkdir(parents=True, exist_ok=True)
    earlier = finished_runs(out) if resume else {}
    # the runs' settings as recorded (a new evaluation writes the record anew)
    settings = _read_settings(out) if resume else {}
    if mismatch := settings_mismatch(out, settings, tasks, earlier.keys()):
        raise ValueError(mismatch)
    if resume and (out / "calibration_frames.csv").is_file():     # today's columns, or refused
        _read_rows(out / "calibration_frames.csv", FRAMES_HEADER, ADDED_FRAME_COLUMNS)
    for name, header in (("runs.csv", RUNS_HEADER), ("calibration.csv", CALIBRATION_HEADER),
                         ("calibration_frames.csv", FRAMES_HEADER)):
        if not (resume and (out / name).is_file()):
            with (out / name).open("w", newline="", encoding="utf-8") as fh:
                csv.writer(fh).writerow(header)
    (out / "failures.txt").unlink(missing_ok=True)
    started = time.monotonic()
    done = {i: earlier[t.key] for i, t in enumerate(tasks) if t.key in earlier}
    if done:
        echo(f"resuming: {len(done)} of {len(tasks)} runs already in {out / 'runs.csv'}")
    earlier_done = set(done)
    todo = [(i, t) for i, t in enumerate(tasks) if i not in done]
    failed: list[RunFailure] = []

    def land(index: int, result: RunResult | RunFailure) -> None:
        count = len(done) + len(failed) + 1
        if isinstance(result, RunFailure):
            failed.append(result)
            with (out / "failures.txt").open("a", encoding="utf-8") as fh:
                fh.write(f"== {asdict(result.key)}\n{result.error}\n")
            last = result.error.strip().splitlines()[-1] if result.error.strip() else "?"
            echo(f"[{count}/{len(tasks)}] FAILED {result.key.scenario} {result.key.map_source} "
                 f"{result.key.policy} seed {result.key.seed}: {last} (traceback in "
                 f"{out / 'failures.txt'}); the other runs go on")
            return
        done[index] = result
        _write_result(out, result)
        settings[_key_text(result.key)] = run_settings(tasks[index])
        _record_settings(out, settings)
        echo(_line(count, len(tasks), result, started, len(earlier_done)))

    executor = executor or LocalExecutor(1)
    for at, outcome in executor.submit_all(run_or_fail, [task for _, task in todo]):
        index, task = todo[at]
        land(index, RunFailure(task.key, outcome.error) if outcome.error
             else outcome.value)  # type: ignore[arg-type]
    return [done[i] for i in sorted(done)], failed
