"""Learning curves: does training beat the actor it started from, and when?

``twinslam train --snapshots`` keeps every validated actor of a run (every ``--validate-every``
slots, the untrained one at slot 0 first). Here each snapshot is scored on held-out episodes —
evaluation seeds 0, 1, … on the covisibility given (a stretch of frames training never saw,
e.g. ``FILE@600:1000`` after training on ``FILE@0:600``) — beside the rule policies and random
on the very same episodes. The checkpoint a run keeps was chosen on its validation seeds of the
training frames, never on these episodes.

Writes ``learning_curve.csv`` (a row per snapshot and per rule: mean υ with a lost frame
scoring 0, its 95 % CI over the episodes, lost share, υ over the tracked frames, the snapshot's
validation υ and whether the run kept it), ``learning_curve_runs.csv`` (every episode of every
snapshot and rule), ``learning_curve_paired.csv`` (each run's kept and last actor against its
own untrained actor and against the best rule, paired by episode, two-level bootstrap over runs
and episodes), ``learning_curve_controls.csv`` (rules, random, the untrained, kept and last
actors side by side, each paired with the best rule) and ``learning_curve.png`` (one line per
run, the rules and the untrained level as horizontal lines, each run's kept snapshot marked).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from twinslam.experiments.parallel import run_all
from twinslam.policies.learned.policy import MbrlPolicy
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import SimConfig
from twinslam.reporting import PairedDifference, mean_ci95, paired_difference, pyplot, write_csv
from twinslam.simulator.covisibility_spec import absolute_spec, cached_covisibility
from twinslam.simulator.evaluation import RunScore, evaluate
from twinslam.sweeps import Executor, TaskFailure
from twinslam.training.trainer import load_snapshots
from twinslam.uncertainty.map_uncertainty import UncertaintyTally

Progress = Callable[[str], None]
RULES = ("lff", "pu", "adapt", "random")


@dataclass(frozen=True)
class Setup:
    """The held-out episodes every snapshot and rule is scored on; the channel and the map
    settings are the training's (read from the snapshots)."""

    covis: str
    channel: str
    rate_range: tuple[float, float]
    vmax: int
    slot_frames: int
    history: int
    episodes: int
    slots: int
    seed0: int = 0

    @property
    def seeds(self) -> list[int]:
        return list(range(self.seed0, self.seed0 + self.episodes))

    def sim_config(self) -> SimConfig:
        return SimConfig(vmax=self.vmax, slot_frames=self.slot_frames, slots=self.slots,
                         history=self.history)


@dataclass(frozen=True)
class CurveTask:
    """One point: a snapshot (file and training slot) or a rule policy, on every episode."""

    setup: Setup
    policy: str                  #: a rule's name, or "" for a snapshot
    snapshots: str = ""          #: the snapshots file
    slot: int = -1               #: the snapshot's training slot


@dataclass(frozen=True)
class CurvePoint:
    task: CurveTask
    runs: list[RunScore]         #: one per episode, in seed order
    validation: float            #: the snapshot's validation υ (NaN for a rule)

    @property
    def per_episode(self) -> np.ndarray:
        return np.array([r.mean_uncertainty for r in self.runs])

    @property
    def pooled(self) -> UncertaintyTally:
        """Every episode's frames together (lost share and tracked υ as the figures pool)."""
        return UncertaintyTally.of(r.tally for r in self.runs)


@functools.lru_cache(maxsize=4)
def _snapshots(path: str) -> tuple[int, int, dict[int, dict[str, Any]]]:
    """A worker loads each snapshots file once (its tasks are that file's slots)."""
    seed, kept, snaps = load_snapshots(Path(path))
    return seed, kept, dict(snaps)


def score_point(task: CurveTask) -> CurvePoint:
    """Play ``task``'s policy on every held-out episode."""
    setup = task.setup
    dataset = cached_covisibility(setup.covis)
    validation = float("nan")
    if task.snapshots:
        blob = _snapshots(task.snapshots)[2][task.slot]
        validation = float(blob["validations"][-1][1])
        policy: MapPolicy = MbrlPolicy.from_blob(blob, f"{task.snapshots}@{task.slot}")
        build: Callable[[str], MapPolicy] = lambda _name: policy  # noqa: E731
        name = "mbrl"
    else:
        build, name = make_policy, task.policy
    result = evaluate([name], dataset, setup.channel, setup.sim_config(), setup.seeds,
                      rate_range=setup.rate_range, make_policy=build)[0]
    return CurvePoint(task, result.runs, validation)


def setup_of(snapshot_files: list[Path], covis: str, episodes: int, slots: int,
             seed0: int = 0) -> tuple[Setup, dict[str, tuple[int, int, list[int]]]]:
    """The held-out setup from the snapshots' training config (all files must agree on
    channel and map settings), and per file (training seed, kept slot, snapshot slots). A
    missing or foreign file is a ValueError now, before any episode is played."""
    if not snapshot_files:
        raise ValueError("no snapshots given (`twinslam train --snapshots` writes them)")
    runs: dict[str, tuple[int, int, list[int]]] = {}
    settings = set()
    for path in snapshot_files:
        if not Path(path).is_file():
            raise ValueError(f"{path}: no such snapshots file")
        seed, kept, snaps = load_snapshots(path)
        if not snaps:
            raise ValueError(f"{path}: holds no snapshots (a training shorter than its "
                             "warm-up and --validate-every?)")
        config = snaps[0][1]["config"]
        settings.add((config["channel"], tuple(config["rate_range"]), int(config["vmax"]),
                      int(config["slot_frames"]), int(config["history"])))
        runs[str(Path(path).resolve())] = (seed, kept, [slot for slot, _ in snaps])
    if len(settings) > 1:
        raise ValueError(f"the snapshots were trained in different settings ({settings}): a "
                         "learning curve compares runs of one setting")
    channel, rate_range, vmax, slot_frames, history = settings.pop()
    return Setup(absolute_spec(covis), channel, rate_range, vmax, slot_frames, history,
                 episodes, slots, seed0), runs


def thinned(slots: list[int], kept: int, every: int) -> list[int]:
    """The snapshot slots scored when only one every ``every`` training slots is wanted:
    those on the grid, and always the first, the last and the kept one (0: all)."""
    if every <= 0:
        return list(slots)
    return [s for s in slots if s % every == 0 or s in (slots[0], slots[-1], kept)]


@dataclass(frozen=True)
class CurveResult:
    """What :func:`learning_curve` scored and wrote: the points, the runs (file → training
    seed, kept slot, snapshot slots), the controls table's rows and the paired comparisons."""

    points: list[CurvePoint]
    runs: dict[str, tuple[int, int, list[int]]]
    controls: list[list[object]]
    paired: dict[str, tuple[int, PairedDifference]]


def learning_curve(snapshot_files: list[Path], covis: str, out_dir: Path, episodes: int = 10,
                   slots: int = 100, seed0: int = 0, progress: Progress | None = None,
                   executor: Executor | None = None,
                   failures: list[TaskFailure] | None = None,
                   every: int = 0) -> CurveResult:
    """Score every snapshot of every run (``every`` > 0: one every that many training slots,
    see :func:`thinned`) and the rules on the held-out episodes; write the CSVs and the
    figure (module docstring)."""
    setup, runs = setup_of(snapshot_files, covis, episodes, slots, seed0)
    tasks = [CurveTask(setup, rule) for rule in RULES]
    tasks += [CurveTask(setup, "", path, slot) for path, (_, kept, slots_) in runs.items()
              for slot in thinned(slots_, kept, every)]
    points = run_all(score_point, tasks, executor, _describe,
                     lambda p: f"{_describe(p.task)}: υ {p.per_episode.mean():.1f}, lost "
                               f"{p.pooled.lost_share:.1%}",
                     progress, out_dir / "learning_curve_failures.txt", failures)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_csv(out_dir / "learning_curve.csv", COLUMNS, [_row(p, runs) for p in points])
    write_csv(out_dir / "learning_curve_runs.csv",
              ["policy", "training_seed", "training_slot", "seed", "mean_uncertainty",
               "lost_share", "tracked_uncertainty"],
              [[_name(p.task), *_run_of(p.task, runs), r.seed, r.mean_uncertainty,
                r.lost_share, r.tracked_uncertainty] for p in points for r in p.runs])
    paired = paired_summary(points, runs)
    write_csv(out_dir / "learning_curve_paired.csv",
              ["comparison", "runs", "episodes", "mean_difference", "ci_low", "ci_high",
               "apart"],
              [[label, n_runs, episodes, d.mean, d.low, d.high, d.apart]
               for label, (n_runs, d) in paired.items()])
    controls = controls_table(points, runs)
    write_csv(out_dir / "learning_curve_controls.csv", CONTROL_COLUMNS, controls)
    if points:
        plot(out_dir / "learning_curve.png", points, runs)
    return CurveResult(points, runs, controls, paired)


COLUMNS = ["policy", "training_seed", "training_slot", "kept", "validation_uncertainty",
           "episodes", "mean_uncertainty", "ci95", "lost_share", "tracked_uncertainty"]


def _describe(task: CurveTask) -> str:
    return task.policy.upper() if task.policy else \
        f"{Path(task.snapshots).name} slot {task.slot}"


def _name(task: CurveTask) -> str:
    return task.policy.upper() if task.policy else "AMM snapshot"


def _run_of(task: CurveTask, runs: dict[str, tuple[int, int, list[int]]]) -> list[object]:
    return [runs[task.snapshots][0], task.slot] if task.snapshots else ["", ""]


def _row(point: CurvePoint, runs: dict[str, tuple[int, int, list[int]]]) -> list[object]:
    task = point.task
    pooled = point.pooled
    kept = runs[task.snapshots][1] == task.slot if task.snapshots else ""
    mean, ci = mean_ci95(list(point.per_episode))
    return [_name(task), *_run_of(task, runs), kept,
            point.validation if task.snapshots else "", len(point.runs), mean, ci,
            pooled.lost_share, pooled.tracked_uncertainty]


def _by_run(points: list[CurvePoint]) -> dict[str, dict[int, CurvePoint]]:
    out: dict[str, dict[int, CurvePoint]] = {}
    for p in points:
        if p.task.snapshots:
            out.setdefault(p.task.snapshots, {})[p.task.slot] = p
    return out


def _best_rule(points: list[CurvePoint]) -> CurvePoint | None:
    """The rule policy (random is a control, not a rule) with the lowest mean υ: what every
    other row is paired with."""
    rules = [p for p in points if p.task.policy and p.task.policy != "random"]
    return min(rules, key=lambda p: p.per_episode.mean()) if rules else None


#: each run's actor a comparison takes: its untrained one, the kept one, the last one
ACTORS = ("untrained", "kept", "last")


def _actor(snaps: dict[int, CurvePoint], kept: int, which: str) -> CurvePoint | None:
    """Run's ``which`` actor (:data:`ACTORS`) among its scored snapshots, or None when that
    point failed."""
    return snaps.get({"untrained": 0, "kept": kept, "last": max(snaps)}[which])


def paired_summary(points: list[CurvePoint], runs: dict[str, tuple[int, int, list[int]]]
                   ) -> dict[str, tuple[int, PairedDifference]]:
    """The kept and the last actor of every run against that run's untrained actor (slot 0)
    and against the best rule, paired by episode: (runs compared, difference). Runs missing
    a needed point (a failed task) are left out of that comparison."""
    best = _best_rule(points)
    out: dict[str, tuple[int, PairedDifference]] = {}
    by_run = _by_run(points)
    for which in ("kept", "last"):
        pairs: list[tuple[CurvePoint, CurvePoint]] = []
        for path, snaps in by_run.items():
            trained_point = _actor(snaps, runs[path][1], which)
            start = _actor(snaps, runs[path][1], "untrained")
            if trained_point is not None and start is not None:
                pairs.append((trained_point, start))
        if not pairs:
            continue
        trained = np.array([a.per_episode for a, _ in pairs])
        untrained = np.array([b.per_episode for _, b in pairs])
        out[f"{which} actor - untrained actor (same run)"] = (
            len(pairs), paired_difference(trained, untrained))
        if best is not None:
            out[f"{which} actor - best rule ({best.task.policy.upper()})"] = (
                len(pairs), paired_difference(trained, best.per_episode))
    return out


def controls_table(points: list[CurvePoint], runs: dict[str, tuple[int, int, list[int]]]
                   ) -> list[list[object]]:
    """The controls beside the trained actor on the held-out episodes: each rule
    and random, the untrained actor of every run (slot 0: one variant over the runs'
    initialisations), the kept and the last actor of every run. Per row: mean υ, its 95 % CI
    (over the episodes for a rule, over the runs' means for a variant), runs, lost share and υ
    tracked pooled over every frame, and the paired difference with the best rule (two-level
    bootstrap over runs and episodes)."""
    best = _best_rule(points)
    if best is None:
        return []
    best_label = best.task.policy.upper()
    singles = {p.task.policy.upper(): [p] for p in points if p.task.policy}
    by_run = _by_run(points)
    labels = {"untrained": "Untrained AMM (slot 0)", "kept": "Trained AMM, kept (validation)",
              "last": "Trained AMM, last"}
    variants: dict[str, list[CurvePoint]] = {}
    for which in ACTORS:
        chosen = (_actor(snaps, runs[path][1], which) for path, snaps in by_run.items())
        variants[labels[which]] = [p for p in chosen if p is not None]
    rows: list[list[object]] = []
    for label, group in {**singles, **variants}.items():
        if not group:
            continue
        scores = np.array([p.per_episode for p in group])
        # a rule: the CI over its episodes; a variant: over its runs' means (NaN under 2)
        _, ci = mean_ci95(list(scores[0] if label in singles else scores.mean(axis=1)))
        pooled = UncertaintyTally.of(r.tally for p in group for r in p.runs)
        diff = paired_difference(scores, best.per_episode)
        rows.append([label, "" if label in singles else len(group), scores.shape[1],
                     float(scores.mean()), ci, pooled.lost_share, pooled.tracked_uncertainty,
                     best_label, *(("", "", "") if label == best_label else
                                   (diff.mean, diff.low, diff.high))])
    return rows


CONTROL_COLUMNS = ["policy", "training_runs", "episodes", "mean_uncertainty", "ci95",
                   "lost_share", "tracked_uncertainty", "best_rule", "paired_vs_best_rule",
                   "paired_ci_low", "paired_ci_high"]


def plot(path: Path, points: list[CurvePoint],
         runs: dict[str, tuple[int, int, list[int]]]) -> None:
    """Held-out mean υ (left) and lost share (right) against training slots: a line per run,
    its kept snapshot ringed; the rules and the runs' mean untrained level as lines across."""
    plt = pyplot()
    fig, (ax, ax_lost) = plt.subplots(1, 2, figsize=(12, 4.4))
    for i, (file, snaps) in enumerate(sorted(_by_run(points).items())):
        seed, kept, _ = runs[file]
        xs = sorted(snaps)
        color = f"C{i % 10}"
        for axis, values in ((ax, [snaps[x].per_episode.mean() for x in xs]),
                             (ax_lost, [100 * snaps[x].pooled.lost_share for x in xs])):
            axis.plot(xs, values, color=color, lw=1.2, label=f"AMM run {seed}")
            if kept in snaps:
                axis.plot([kept], [values[xs.index(kept)]], "o", mfc="none", color=color,
                          ms=9)
    untrained = [s[0] for s in _by_run(points).values() if 0 in s]
    lines = [(p.task.policy.upper(), p) for p in points if p.task.policy]
    if untrained:
        ax.axhline(np.mean([p.per_episode.mean() for p in untrained]), color="k", ls=":",
                   label="untrained (mean of runs)")
        ax_lost.axhline(100 * np.mean([p.pooled.lost_share for p in untrained]), color="k",
                        ls=":")
    # the runs (and their untrained start) set the υ scale; a rule far off it is named in the
    # legend with its value rather than squashing the curves flat
    curve = [p.per_episode.mean() for s in _by_run(points).values() for p in s.values()]
    lo, hi = (min(curve), max(curve)) if curve else (0.0, 1.0)
    pad = max(0.5 * (hi - lo), 20.0)
    for j, (label, p) in enumerate(lines):
        style = {"color": "grey", "ls": ("--", "-.", (0, (5, 1)), (0, (1, 2)))[j % 4]}
        value = p.per_episode.mean()
        off = not lo - pad <= value <= hi + pad
        ax.axhline(value, label=f"{label} (off scale: {value:.0f})" if off else label,
                   **style)
        ax_lost.axhline(100 * p.pooled.lost_share, label=label, **style)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("held-out mean υ, lost frame = 0 (lower is better)")
    ax_lost.set_ylabel("held-out lost next-slot frames (%)")
    for axis in (ax, ax_lost):
        axis.set_xlabel("training slots (ringed: the kept checkpoint, chosen on validation)")
    ax.legend(fontsize=7, ncol=2)
    ax_lost.set_yscale("symlog", linthresh=1.0)       # 0.8 % and 50 % on one axis
    ax_lost.set_ylim(bottom=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
