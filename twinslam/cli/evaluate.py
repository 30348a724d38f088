"""``twinslam evaluate``: the live system as the judge of map management (issues #19, #27).

Runs the nodes — player, device, edge — as processes on a private loopback domain, once per
scenario × device map source × policy × seed (the seed drives the uplink's channel model, and
the walk when the sequence is the synthetic room), and reports what a user of the device would
see: ATE and RPE against ground truth (evo), tracking failures, relocalisations and time to
recover, the edge's υ and lost share, uploads and edge milliseconds per slot. Every run is a
row of ``runs.csv`` (written as it finishes, so an interrupted evaluation keeps what it
measured); ``summary.csv`` and ``summary.md`` hold mean ± 95 % CI over the seeds per scenario
× map source × policy, ``summary.png`` plots them.

Each run is also a calibration of the simulator against the device
(:mod:`twinslam.cli.live_calibration`): ``calibration.csv`` has, per run, the share of
next-slot frames the simulator's rule calls lost beside the share the device failed, the
precision and recall of "lost" for "device failure", and Spearman's ρ of u with the device's
translation error and inlier count; ``calibration_frames.csv`` has every frame. Runs go to
``--jobs`` worker processes, each on a loopback domain of its own.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, fields
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from twinslam.cli.launcher import LaunchConfig, Launcher, RunReport
from twinslam.cli.live_calibration import LiveFrames, live_frames, played_frames
from twinslam.cli.scenarios import Scenario
from twinslam.common.reporting import mean_ci95, pearson_r, pyplot, write_csv
from twinslam.common.tracking_rule import MIN_SHARED_POINTS
from twinslam.node_hosts.loopback import LoopbackDomain
from twinslam.policy_registry import LEARNED_PREFIX
from twinslam.simulator.calibration import Calibration, calibrate
from twinslam.simulator.covisibility import load_covisibility
from twinslam.slam.map_source import MAP_SOURCES

#: the figures summarised per scenario × policy: (field, column title, unit); the fields are
#: RunReport's, and the calibration's two shares
METRICS = (("ate_m", "ATE", "m"), ("rpe_m", "RPE 1 s", "m"),
           ("tracking_failures", "failures", ""), ("relocalisations", "relocalisations", ""),
           ("recover_s", "recover", "s"), ("untracked_frames", "untracked", "frames"),
           # the device's failures among the scored next-slot frames, beside what the
           # simulator's rule predicted for them (calibration.csv)
           ("device_failure_share", "device failed", ""),
           ("predicted_lost_share", "predicted lost", ""),
           # MapStats' υ three ways: a lost next-slot frame scoring 0, the lost share, and
           # the tracked frames only (DESIGN.md §2)
           ("mean_uncertainty", "mean υ", ""), ("lost_ratio", "lost share", ""),
           ("tracked_uncertainty", "υ tracked", ""),
           ("frames_uploaded", "uploads", "frames"), ("edge_ms_median", "edge", "ms/slot"))
#: the figures a paired comparison with the best rule policy is made on (lower is better)
PAIRED = ("tracking_failures", "untracked_frames", "device_failure_share", "ate_m",
          "mean_uncertainty")
#: the rule policies a learned one is compared with
RULE_POLICIES = ("lff", "pu", "adapt", "random")


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


def policy_variants(text: str) -> list[tuple[str, str]]:
    """``--policy`` items as (label, edge policy): ``LABEL=POLICY`` or ``POLICY`` (labelled
    ``mbrl:<checkpoint name>`` for a learned one); a label given to several checkpoints pools
    their training runs in every table."""
    out = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        label, sep, spec = item.partition("=")
        if not sep:
            label, spec = item, item
            kind, colon, path = item.partition(":")
            if colon:
                label = f"{kind}:{Path(path).stem}"
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


@dataclass
class RunResult:
    key: RunKey
    report: RunReport
    frames: LiveFrames | None     #: None without a covisibility dataset
    calibration: Calibration | None


def sequence_for(sequence: str, seed: int) -> str:
    """The synthetic room walks a seed's own path; a recorded sequence is what it is."""
    if not sequence.startswith("synthetic"):
        return sequence
    frames = sequence.partition(":")[2].partition(":")[0]
    return f"synthetic:{frames or 900}:{seed}"


def run_one(task: RunTask) -> RunResult:
    """Play one run on a loopback domain of its own; calibrate it when a dataset is given.

    A learned policy's run also starts the twin node with the policy's checkpoint, so the
    policy decides on the twin's latents (``/udt/rate_latent``) as on a deployed edge; without
    it a twin-driven policy would hand every slot to the edge's fallback policy."""
    key = task.key
    extra = {"device_tracker": [f"seed:={key.seed}", f"map_source:={key.map_source}"]}
    kind, _, checkpoint = key.edge_policy.partition(":")
    learned = kind == LEARNED_PREFIX and bool(checkpoint)
    if learned:
        extra["udt_node"] = [f"policy_checkpoint:={checkpoint}"]
    config = LaunchConfig(task.sequence, key.edge_policy, task.frames, 1.0, task.params,
                          timeout_s=task.timeout_s, scenario=task.scenario, extra=extra,
                          start=task.start, with_twin=learned)
    with LoopbackDomain() as dom:
        dom.activate()
        launcher = Launcher(dom, config, print if task.verbose else None)
        report = launcher.run()
    if task.covis is None or launcher.record is None:
        return RunResult(key, report, None, None)
    dataset = load_covisibility(task.covis)
    played = played_frames(task.sequence, task.frames, task.scenario, dataset,
                           start=task.start)
    frames = live_frames(launcher.record, dataset, played)
    return RunResult(key, report, frames,
                     calibrate((f.calibration for f in frames.frames), MIN_SHARED_POINTS))


RUNS_HEADER = [f.name for f in fields(RunKey)] + [f.name for f in fields(RunReport)]
CALIBRATION_HEADER = [f.name for f in fields(RunKey)] + [
    "min_shared", "startup_frames", "unplaced_frames", *[f.name for f in fields(Calibration)]]
FRAMES_HEADER = [f.name for f in fields(RunKey)] + [
    "slot", "position", "frame_id", "row", "map_version", "shared_points", "covisibility",
    "uncertainty", "shared_points_tracked_map", "covisibility_tracked_map",
    "uncertainty_tracked_map", "device_tracked", "inliers", "translation_error_m"]


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
         f.calibration.translation_error_m]
        for f in result.frames.frames])


def _line(i: int, total: int, r: RunResult, started: float, resumed: int = 0) -> str:
    elapsed = time.monotonic() - started
    eta = elapsed / max(i - resumed, 1) * (total - i)
    rep, cal = r.report, r.calibration
    side = (f", predicted lost {cal.predicted_lost_share:.1%} vs device failed "
            f"{cal.device_failure_share:.1%}" if cal is not None else "")
    return (f"[{i}/{total}] {r.key.scenario:<13} {r.key.map_source:<10} {rep.label:<14} seed "
            f"{r.key.seed}: ATE {rep.ate_m:.3f} m, {rep.tracking_failures} failures, "
            f"{rep.relocalisations} relocalisations, υ {rep.mean_uncertainty:.1f}{side} "
            f"({elapsed / 60:.1f} min, ~{eta / 60:.1f} min left)")


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
_CELL = {"int": int, "float": float, "str": str}


def _read_rows(path: Path, header: list[str]) -> list[list[str]]:
    """The rows of one of the tables :func:`run_all` writes, by position: runs.csv has two
    ``policy`` columns (the label and the report's)."""
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows or rows[0] != header:
        raise ValueError(f"{path} was written by another version of twinslam evaluate "
                         f"(its columns differ); resume into a new --out folder")
    return rows[1:]


def _typed(cls: type, cells: list[str]) -> object:
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


def run_all(tasks: list[RunTask], out: Path, jobs: int = 1,
            echo: Callable[[str], None] = print,
            resume: bool = False) -> tuple[list[RunResult], list[RunFailure]]:
    """Every task, ``jobs`` at a time in worker processes (1: in this process, one after the
    other); each result's rows appended as it lands, a failed run reported (its traceback in
    ``failures.txt``) while the rest go on. With ``resume``, the runs ``out`` already holds
    are read back instead of run again (a failed one is tried again). The results in task
    order, and the failures."""
    out.mkdir(parents=True, exist_ok=True)
    earlier = finished_runs(out) if resume else {}
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
        echo(_line(count, len(tasks), result, started, len(earlier_done)))

    if jobs <= 1:
        for i, task in todo:
            land(i, run_or_fail(task))
    elif todo:
        pool = ProcessPoolExecutor(jobs, mp_context=get_context("spawn"))
        try:
            futures = {pool.submit(run_or_fail, task): i for i, task in todo}
            for future in as_completed(futures):
                land(futures[future], future.result())
        finally:        # an interrupt must not wait for every queued run
            pool.shutdown(wait=True, cancel_futures=True)
    return [done[i] for i in sorted(done)], failed


def side_by_side(results: list[RunResult]) -> list[str]:
    """One line per run: what the device lived through beside what the simulator's rule
    predicted for the same frames (the table ``make run`` prints)."""
    lines = [f"{'policy':<14} {'map source':<10} {'fails':>5} {'reloc':>5} {'untrk':>5} "
             f"{'ATE m':>6} {'RPE m':>6} {'predicted lost':>14} {'device failed':>13} "
             f"{'uploads':>7} {'edge ms':>7}"]
    for r in results:
        rep, cal = r.report, r.calibration
        predicted = f"{cal.predicted_lost_share:.1%}" if cal else "–"
        failed = f"{cal.device_failure_share:.1%}" if cal else "–"
        lines.append(f"{rep.label:<14} {r.key.map_source:<10} {rep.tracking_failures:>5d} "
                     f"{rep.relocalisations:>5d} {rep.untracked_frames:>5d} {rep.ate_m:>6.3f} "
                     f"{rep.rpe_m:>6.3f} {predicted:>14} {failed:>13} "
                     f"{rep.frames_uploaded:>7d} {rep.edge_ms_median:>7.0f}")
    return lines


def agreement_over_runs(results: list[RunResult]) -> dict[str, tuple[float, int]]:
    """Per map source: Pearson's r over runs between the predicted lost share and the
    device's failure share, and how many runs (r is NaN below 3 runs or without spread)."""
    out = {}
    for source in dict.fromkeys(r.key.map_source for r in results):
        pairs = [(r.calibration.predicted_lost_share, r.calibration.device_failure_share)
                 for r in results if r.key.map_source == source and r.calibration is not None
                 and r.calibration.frames]
        predicted, failed = zip(*pairs, strict=True) if pairs else ((), ())
        out[source] = (pearson_r(np.array(predicted), np.array(failed)), len(pairs))
    return out


@dataclass
class SummaryRow:
    scenario: str
    map_source: str
    policy: str
    runs: int
    figures: dict[str, tuple[float, float]]      #: metric → (mean, 95 % half-width)


def figures_of(result: RunResult) -> dict[str, float]:
    """Every figure of :data:`METRICS` one run measured (NaN where it could not)."""
    cal = result.calibration
    shares = {"device_failure_share": cal.device_failure_share if cal else math.nan,
              "predicted_lost_share": cal.predicted_lost_share if cal else math.nan}
    return {m: shares[m] if m in shares else float(getattr(result.report, m))
            for m, _, _ in METRICS}


def summarise(results: list[RunResult]) -> list[SummaryRow]:
    """Mean ± CI over runs per scenario × map source × policy label (a label's training runs
    pooled with its seeds), in the order the runs came."""
    groups: dict[tuple[str, str, str], list[dict[str, float]]] = {}
    for r in results:
        groups.setdefault((r.key.scenario, r.key.map_source, r.key.policy), []).append(
            figures_of(r))
    return [SummaryRow(scenario, source, policy, len(runs),
                       {m: mean_ci95([f[m] for f in runs]) for m, _, _ in METRICS})
            for (scenario, source, policy), runs in groups.items()]


@dataclass(frozen=True)
class PairedRow:
    scenario: str
    map_source: str
    metric: str
    best: str                 #: the rule policy with the lowest mean on this metric
    policy: str
    seeds: int                #: seeds both ran
    difference: float         #: mean over seeds of (policy - best); a label's runs averaged
    ci95: float               #: Student-t half-width over the seeds


def paired_differences(results: list[RunResult]) -> list[PairedRow]:
    """Per scenario, map source and metric of :data:`PAIRED`: every policy against the rule
    policy with the lowest mean, seed by seed (the same walk and uplink draws), a label's
    training runs averaged within a seed first."""
    cells: dict[tuple[str, str], dict[str, dict[int, list[dict[str, float]]]]] = {}
    for r in results:
        cell = cells.setdefault((r.key.scenario, r.key.map_source), {})
        cell.setdefault(r.key.policy, {}).setdefault(r.key.seed, []).append(figures_of(r))
    rows = []
    for (scenario, source), by_policy in cells.items():
        for metric in PAIRED:
            seeds = {p: _per_seed(runs, metric) for p, runs in by_policy.items()}
            rules = [p for p in by_policy if p in RULE_POLICIES and seeds[p]]
            if not rules:
                continue
            best = min(rules, key=lambda p: float(np.mean(list(seeds[p].values()))))
            base = seeds[best]
            for policy in by_policy:
                if policy == best:
                    continue
                mine = seeds[policy]
                common = sorted(set(mine) & set(base))
                mean, half = mean_ci95([mine[s] - base[s] for s in common])
                rows.append(PairedRow(scenario, source, metric, best, policy, len(common),
                                      mean, half))
    return rows


def _per_seed(runs: dict[int, list[dict[str, float]]], metric: str) -> dict[int, float]:
    """A policy's ``metric`` per seed, its runs of the seed averaged (NaN ones left out)."""
    return {seed: float(np.nanmean([f[metric] for f in group]))
            for seed, group in runs.items() if not all(math.isnan(f[metric]) for f in group)}


def paired_markdown(rows: list[PairedRow]) -> str:
    lines = ["| scenario | map source | figure | best rule policy | policy | seeds | "
             "difference (policy - best) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        digits = 3 if r.metric in ("ate_m", "device_failure_share") else 1
        half = "" if math.isnan(r.ci95) else f" ± {r.ci95:.{digits}f}"
        apart = " (CI excludes 0)" if not math.isnan(r.ci95) and abs(r.difference) > r.ci95 \
            else ""
        lines.append(f"| {r.scenario} | {r.map_source} | {r.metric} | {r.best} | {r.policy} | "
                     f"{r.seeds} | {r.difference:+.{digits}f}{half}{apart} |")
    return "\n".join(lines)


def _cell(mean: float, half: float, metric: str) -> str:
    if math.isnan(mean):
        return "–"
    digits = {"ate_m": 3, "rpe_m": 3, "recover_s": 2, "lost_ratio": 3,
              "device_failure_share": 3, "predicted_lost_share": 3}.get(metric, 1)
    return f"{mean:.{digits}f}" + ("" if math.isnan(half) else f" ± {half:.{digits}f}")


def markdown_table(rows: list[SummaryRow]) -> str:
    titles = [f"{t} ({u})" if u else t for _, t, u in METRICS]
    lines = ["| scenario | map source | policy | runs | " + " | ".join(titles) + " |",
             "|" + "---|" * (4 + len(METRICS))]
    for r in rows:
        cells = [_cell(*r.figures[m], m) for m, _, _ in METRICS]
        lines.append(f"| {r.scenario} | {r.map_source} | {r.policy} | {r.runs} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_summary(rows: list[SummaryRow], out: Path) -> None:
    header = ["scenario", "map_source", "policy", "runs"] + [
        f"{m}{s}" for m, _, _ in METRICS for s in ("_mean", "_ci95")]
    write_csv(out / "summary.csv", header,
              [[r.scenario, r.map_source, r.policy, r.runs,
                *(v for m, _, _ in METRICS for v in r.figures[m])] for r in rows])
    (out / "summary.md").write_text(markdown_table(rows) + "\n", encoding="utf-8")
    plot(rows, out / "summary.png")


def write_paired(rows: list[PairedRow], out: Path) -> None:
    write_csv(out / "paired.csv", [f.name for f in fields(PairedRow)],
              [list(asdict(r).values()) for r in rows])
    (out / "paired.md").write_text(paired_markdown(rows) + "\n", encoding="utf-8")


def plot(rows: list[SummaryRow], path: Path) -> None:
    """Grouped bars (scenario groups, one bar per policy) with 95 % CIs, one panel per figure
    a user weighs: ATE, failures, untracked frames, the device's failure share beside the
    simulator's predicted lost share, mean υ."""
    plt = pyplot()
    panels = ("ate_m", "tracking_failures", "untracked_frames", "device_failure_share",
              "predicted_lost_share", "mean_uncertainty")
    sources = {r.map_source for r in rows}

    def group(r: SummaryRow) -> str:
        return r.scenario if len(sources) == 1 else f"{r.scenario}\n{r.map_source}"

    scenarios = list(dict.fromkeys(group(r) for r in rows))
    policies = list(dict.fromkeys(r.policy for r in rows))
    width = 0.8 / max(len(policies), 1)
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
    for ax, metric in zip(axes.ravel(), panels, strict=True):
        _, title, unit = next(m for m in METRICS if m[0] == metric)
        for j, policy in enumerate(policies):
            xs, means, halves = [], [], []
            for i, scenario in enumerate(scenarios):
                row = next((r for r in rows if group(r) == scenario and r.policy == policy),
                           None)
                if row is not None:
                    mean, half = row.figures[metric]
                    xs.append(i + (j - (len(policies) - 1) / 2) * width)
                    means.append(mean)
                    halves.append(0.0 if math.isnan(half) else half)
            ax.bar(xs, means, width, yerr=halves, capsize=3, label=policy)
        ax.set_xticks(range(len(scenarios)), scenarios, rotation=15)
        ax.set_title(f"{title} ({unit})" if unit else title)
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].legend()
    fig.suptitle("live pipeline per scenario" + (" and device map source" if len(sources) > 1
                 else f" ({next(iter(sources))} map source)") + " and policy: mean and 95 % "
                 "CI over seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser, default_sequence: str,
                  default_params: Path, scenario_names: list[str]) -> None:
    parser.add_argument("--sequence", default=default_sequence,
                        help="SUN3D / 7-Scenes / TUM folder, MCAP bag (forward only), or "
                        "synthetic[:frames] (each seed walks its own path); default: "
                        "%(default)s")
    parser.add_argument("--frames", type=int, default=300,
                        help="frames of the sequence per run (revisit scenarios play them "
                        "forward then back: 2x-1); default %(default)s")
    parser.add_argument("--start", type=int, default=0,
                        help="the sequence's first frame played (e.g. keep a stretch for "
                        "tuning apart from the one evaluated); default %(default)s")
    parser.add_argument("--policy", default="lff,pu,adapt",
                        help="comma-separated: lff, pu, adapt, random, mbrl:CHECKPOINT, each "
                        "optionally LABEL=POLICY (several checkpoints under one label: one "
                        "variant over its training runs); default %(default)s")
    parser.add_argument("--scenario", default=",".join(scenario_names),
                        help="comma-separated, of: " + ", ".join(scenario_names)
                        + "; default all")
    parser.add_argument("--map-source", default="edge",
                        help="the device's map source(s), comma-separated, of: "
                        + ", ".join(MAP_SOURCES) + " (edge: the paper's device, tracked only "
                        "against the edge's map; edge+local: plus its own recent points); "
                        "default %(default)s")
    parser.add_argument("--seeds", type=int, default=3,
                        help="runs per scenario, map source and policy; default %(default)s")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="seeds are FIRST..FIRST+SEEDS-1 (keep tuning seeds apart from "
                        "evaluation seeds); default %(default)s")
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs at a time, each in a worker process on its own loopback "
                        "domain (a run needs about one core); default %(default)s")
    parser.add_argument("--params", type=Path, default=default_params,
                        help="ROS 2 parameter file for the nodes; default %(default)s")
    parser.add_argument("--out", type=Path, default=Path("results/live"),
                        help="folder for runs.csv, summary.csv/.md/.png, calibration.csv, "
                        "calibration_frames.csv (and covis/, the played frames' "
                        "covisibility); default %(default)s")
    parser.add_argument("--resume", action="store_true",
                        help="keep the runs --out already holds (an interrupted evaluation) "
                        "and run only the missing ones; the tables cover both")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds one run may take before its nodes are stopped; default "
                        "%(default)s")
    parser.add_argument("--verbose", action="store_true",
                        help="print every slot's status line, not only one line per run")
