"""Paper Figs 7–9: mean pose-estimation uncertainty υ of the learned and the rule-based
policies beside the clairvoyant reference plan (a search, not a bound) and the Hadamard lower
bound (no plan scores below it), on held-out seeds
(0, 1, … — training uses ``TRAINING_SEED_BASE`` + …, so no evaluated channel realisation or
start frame was trained on).

* **fig7** — υ vs the share of high-rate slots of a 2-state chain (one interval).
* **fig8** — N = 2 vs N = 4 rate states at the same mean rate (doubly stochastic chains, whose
  stationary distribution is uniform: 60 Mbit/s on 40–80 for every N).
* **fig9** — υ vs V_max ∈ {25, …, 45} with a non-stationary chain: three intervals per episode.

A learned variant is given as ``label=CHECKPOINT`` once per training run (the same label
repeated: its runs); each figure's CSV has one row per (x, policy) with mean υ (a lost frame
scoring 0), its 95 % confidence half-width (Student t: over the evaluation episodes for a rule
policy, over the training runs' means for a learned variant), the training runs, the episodes,
the share of lost next-slot frames and υ over the tracked frames; ``{figure}_runs.csv`` has
every episode of every run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twinslam.experiments.parallel import run_all
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.reporting import PairedDifference, mean_ci95, paired_difference, pyplot, write_csv
from twinslam.simulator.covisibility_spec import absolute_spec, cached_covisibility
from twinslam.simulator.evaluation import PolicyResult, PooledScores, RunScore, evaluate
from twinslam.simulator.lower_bound import slot_lower_bounds
from twinslam.slot_protocol import table1
from twinslam.sweeps import Executor, TaskFailure
from twinslam.uncertainty.map_uncertainty import UncertaintyTally
from twinslam.uplink.channels import parse_channel

Progress = Callable[[str], None]
RULES = ("lff", "pu", "adapt")
#: the control every figure has beside the rules: uniform random uploads and evictions
CONTROLS = ("random",)
#: the label of the untrained paper's actor (the initial actor of training runs 0, 1, …)
UNTRAINED = "Untrained AMM"


@dataclass(frozen=True)
class Setting:
    runs: int = 15
    slots: int = 200
    vmax: int = table1.VMAX
    seed0: int = 0
    reference_swaps: int = 100     #: the reference's local-search replays per episode


@dataclass
class VariantResult(PooledScores):
    """A learned variant over its training runs (one checkpoint each): the mean and the 95 %
    CI are over the runs' means — how much the result depends on the training seed — never
    the best run's; lost share and tracked υ pool every episode of every run."""

    label: str
    checkpoints: list[PolicyResult]

    @property
    def per_seed(self) -> list[float]:
        return [v for c in self.checkpoints for v in c.per_seed]

    @property
    def run_means(self) -> list[float]:
        return [c.mean for c in self.checkpoints]

    @property
    def mean(self) -> float:
        return float(np.mean(self.run_means))

    @property
    def ci95(self) -> float:
        return (mean_ci95(self.run_means)[1] if len(self.checkpoints) > 1
                else self.checkpoints[0].ci95)

    @property
    def pooled(self) -> UncertaintyTally:
        return UncertaintyTally.of(c.pooled for c in self.checkpoints)


@dataclass
class BoundResult:
    """The Hadamard lower bound per evaluation seed (:mod:`twinslam.simulator.lower_bound`):
    no plan scores below it; it loses and tracks no frames of its own."""

    per_seed: list[float]

    @property
    def mean(self) -> float:
        return float(np.mean(self.per_seed))

    @property
    def ci95(self) -> float:
        return mean_ci95(self.per_seed)[1]

    lost_share = math.nan
    tracked_uncertainty = math.nan


Result = PolicyResult | VariantResult | BoundResult
BOUND = "Lower bound (Hadamard)"


@dataclass(frozen=True)
class Episode:
    """One task of a sweep: every policy (``specs``) on one seed of one x. The dataset
    travels as its spec (:mod:`twinslam.simulator.covisibility_spec`), each worker loading
    it once."""

    x: object
    covis: str
    channel: str
    setting: Setting
    specs: tuple[str, ...]
    seed: int
    reference: bool


@dataclass
class EpisodeResult:
    """An :class:`Episode`'s score per policy spec (its label among them), and the Hadamard
    bound of its seed (NaN without the reference)."""

    episode: Episode
    runs: dict[str, tuple[str, RunScore]]
    bound: float


def play_episode(episode: Episode) -> EpisodeResult:
    """Every policy of ``episode`` on its seed (the reference starts from all their plans)."""
    dataset = cached_covisibility(episode.covis)
    setting = episode.setting
    config = SimConfig(vmax=setting.vmax, slots=setting.slots)
    results = evaluate(list(episode.specs), dataset, episode.channel, config, [episode.seed],
                       make_policy=make_policy, reference_swaps=setting.reference_swaps)
    bound = math.nan
    if episode.reference:
        env = MapManagementEnv(dataset, parse_channel(episode.channel, seed=episode.seed),
                               config)
        bound = float(np.mean(slot_lower_bounds(env, episode.seed)))
    return EpisodeResult(episode, {spec: (res.policy, res.runs[0])
                                   for spec, res in zip(episode.specs, results, strict=True)},
                         bound)


def _collect(episodes: list[EpisodeResult], learned: dict[str, list[Path]], reference: bool
             ) -> tuple[dict[str, Result], list[list[object]]]:
    """One x's results by label from its episodes (in seed order), and one row per episode
    (label, checkpoint, seed, mean υ, lost share, tracked υ)."""
    episodes = sorted(episodes, key=lambda e: e.episode.seed)
    specs = episodes[0].episode.specs

    def result(spec: str) -> PolicyResult:
        return PolicyResult(episodes[0].runs[spec][0], [e.runs[spec][1] for e in episodes])

    found = {spec: result(spec) for spec in specs}
    out: dict[str, Result] = {name.upper(): found[name] for name in (*RULES, *CONTROLS)}
    for label, paths in learned.items():
        out[label] = VariantResult(label, [found[f"mbrl:{p}"] for p in paths])
    if reference:
        out[REFERENCE] = found["reference"]
        out[BOUND] = BoundResult([e.bound for e in episodes])
    rows = [[label, str(path) if path else "", run.seed, run.mean_uncertainty,
             run.lost_share, run.tracked_uncertainty]
            for label, path, res in (
                *((n.upper(), None, found[n]) for n in (*RULES, *CONTROLS)),
                *((label, p, found[f"mbrl:{p}"]) for label, paths in learned.items()
                  for p in paths),
                *(((REFERENCE, None, found["reference"]),) if reference else ()))
            for run in res.runs]
    return out, rows


REFERENCE = "Reference (clairvoyant search)"


def sweep(name: str, xs: list[object], channel_of: Callable[[object], str],
          setting_of: Callable[[object], Setting], covis: str,
          learned: dict[str, list[Path]], out_dir: Path, x_label: str, reference: bool = True,
          progress: Progress | None = None, plot: bool = True,
          executor: Executor | None = None, failures: list[TaskFailure] | None = None
          ) -> dict[object, dict[str, Result]]:
    """Every policy at every x, one task per (x, seed) on ``executor`` (None: this process);
    writes ``{name}.csv`` (a row per x and policy), ``{name}_runs.csv`` (a row per episode:
    every run reported) and ``{name}.png``. A failed episode is added to ``failures`` (its
    traceback in ``{name}_failures.txt``) and its seed is left out of that x, for every
    policy alike (the comparisons stay paired)."""
    specs = (*RULES, *CONTROLS, *(f"mbrl:{p}" for paths in learned.values() for p in paths),
             *(("reference",) if reference else ()))
    covis = absolute_spec(covis)
    tasks = [Episode(x, covis, channel_of(x), setting_of(x), specs, seed, reference)
             for x in xs
             for seed in range(setting_of(x).seed0, setting_of(x).seed0 + setting_of(x).runs)]
    done = run_all(play_episode, tasks, executor,
                   lambda e: f"{name} x={e.x} seed {e.seed}",
                   lambda r: f"{name} x={r.episode.x} seed {r.episode.seed}: " + ", ".join(
                       f"{label} {run.mean_uncertainty:.1f}" for label, run in
                       (r.runs[n] for n in RULES)), progress,
                   out_dir / f"{name}_failures.txt", failures)
    results: dict[object, dict[str, Result]] = {}
    episodes: list[list[object]] = []
    for x in xs:
        mine = [r for r in done if r.episode.x == x]
        if not mine:
            continue
        results[x], rows = _collect(mine, learned, reference)
        episodes += [[x, *row] for row in rows]
        if progress:
            for label, res in results[x].items():
                progress(f"{channel_of(x)} V_max {setting_of(x).vmax}: {label} "
                         f"{res.mean:.1f} ± {res.ci95:.1f}, lost {res.lost_share:.1%}, "
                         f"tracked {res.tracked_uncertainty:.1f}")
    write_csv(out_dir / f"{name}.csv", [x_label, *COLUMNS], _rows(results))
    write_csv(out_dir / f"{name}_runs.csv", [x_label, *RUN_COLUMNS], episodes)
    if plot and results:
        plot_figure(out_dir / f"{name}.png", results, x_label)
    return results


COLUMNS = ["policy", "mean_uncertainty", "ci95", "training_runs", "episodes", "lost_share",
           "tracked_uncertainty", "best_rule", "paired_vs_best_rule", "paired_ci_low",
           "paired_ci_high"]
RUN_COLUMNS = ["policy", "checkpoint", "seed", "mean_uncertainty", "lost_share",
               "tracked_uncertainty"]


def run_episode_scores(result: Result) -> np.ndarray | None:
    """Mean υ per training run × evaluation episode (a rule policy: one run); None for the
    bound, which pairs with nothing."""
    if isinstance(result, VariantResult):
        return np.array([c.per_seed for c in result.checkpoints])
    if isinstance(result, PolicyResult):
        return np.array([result.per_seed])
    return None


def best_rule(by: dict[str, Result]) -> str:
    """The rule policy with the lowest mean υ at one point: what every other is paired with."""
    return min((name.upper() for name in RULES), key=lambda label: by[label].mean)


def paired_rows(by: dict[str, Result]) -> dict[str, PairedDifference | None]:
    """Per label: the paired difference to :func:`best_rule` on the same episodes
    (:func:`twinslam.reporting.paired_difference`: Student's t for a rule, a two-level
    bootstrap over training runs and episodes for a learned variant); None for the bound."""
    baseline = by[best_rule(by)].per_seed
    out: dict[str, PairedDifference | None] = {}
    for label, result in by.items():
        scores = run_episode_scores(result)
        out[label] = None if scores is None else paired_difference(scores, baseline)
    return out


def _rows(results: dict[object, dict[str, Result]]) -> list[list[object]]:
    rows: list[list[object]] = []
    for x, by in results.items():
        best, paired = best_rule(by), paired_rows(by)
        for label, r in by.items():
            diff = paired[label]
            rows.append([x, label, r.mean, r.ci95,
                         len(r.checkpoints) if isinstance(r, VariantResult) else "",
                         len(r.per_seed), r.lost_share, r.tracked_uncertainty, best,
                         *((diff.mean, diff.low, diff.high) if diff else ("", "", ""))])
    return rows


def untrained_checkpoints(covis: str, channel: str, out_dir: Path, inits: int) -> list[Path]:
    """The paper's actor as training runs 0 … ``inits`` - 1 start it (their seeds draw its
    initial weights), saved untrained under ``out_dir``/untrained: the control that says
    whether training did anything."""
    # torch loads here, not with the module: a sweep of the rules (and each of its worker
    # processes) never needs it, and it costs seconds of CPU per process
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    dataset = cached_covisibility(absolute_spec(covis))
    n_states = parse_channel(channel).n_states
    folder = out_dir / "untrained"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for seed in range(inits):
        path = folder / f"paper_n{n_states}_s{seed}.pt"
        AmmTrainer(TrainConfig(channel=channel, actor="paper", seed=seed, validate_every=0),
                   dataset).save(path)
        paths.append(path)
    return paths


def _with_controls(learned: dict[str, list[Path]], covis: str, channel: str, out_dir: Path,
                   controls: int) -> dict[str, list[Path]]:
    if controls <= 0:
        return learned
    return {UNTRAINED: untrained_checkpoints(covis, channel, out_dir, controls), **learned}


def fig7(covis: str, learned: dict[str, list[Path]], out_dir: Path,
         setting: Setting = Setting(), ratios: tuple[float, ...] = (0.2, 0.35, 0.5, 0.65, 0.8),
         progress: Progress | None = None, executor: Executor | None = None,
         failures: list[TaskFailure] | None = None, controls: int = 5
         ) -> dict[object, dict[str, Result]]:
    """``controls``: untrained initialisations of the paper's actor beside the rules and
    random (0: none)."""
    learned = _with_controls(learned, covis, "markov:N=2", out_dir, controls)
    return sweep("fig7", list(ratios), lambda r: f"markov:N=2,ratio={r}", lambda _r: setting,
                 covis, learned, out_dir, "ratio of high-rate slots", progress=progress,
                 executor=executor, failures=failures)


def fig8(covis: str, learned: dict[int, dict[str, list[Path]]],
         out_dir: Path, setting: Setting = Setting(), progress: Progress | None = None,
         executor: Executor | None = None, failures: list[TaskFailure] | None = None,
         controls: int = 5) -> dict[object, dict[str, Result]]:
    """``learned`` per N: each N has its own trained policies (the state's one-hot rate
    history has N columns), and its own untrained controls."""
    results: dict[object, dict[str, Result]] = {}
    def channel(n: object) -> str:
        return f"markov:N={n},balanced"

    for n, policies in (learned or {2: {}}).items():
        policies = _with_controls(policies, covis, channel(n), out_dir, controls)
        results.update(sweep(f"fig8_n{n}", [n], channel,
                             lambda _m: setting, covis, policies, out_dir,
                             "number of rate states N", progress=progress, plot=False,
                             executor=executor, failures=failures))
    write_csv(out_dir / "fig8.csv", ["number of rate states N", *COLUMNS], _rows(results))
    if results:
        plot_figure(out_dir / "fig8.png", results, "number of rate states N", bars=True)
    return results


def fig9(covis: str, learned: dict[str, list[Path]], out_dir: Path,
         setting: Setting = Setting(), vmaxes: tuple[int, ...] = (25, 30, 35, 40, 45),
         progress: Progress | None = None, executor: Executor | None = None,
         failures: list[TaskFailure] | None = None, controls: int = 5
         ) -> dict[object, dict[str, Result]]:
    interval = max(1, setting.slots // 3)
    channel = f"markov:N=2,K={interval},nonstationary"
    learned = _with_controls(learned, covis, channel, out_dir, controls)
    return sweep("fig9", list(vmaxes), lambda _v: channel,
                 lambda v: replace(setting, vmax=int(v)),  # type: ignore[call-overload]
                 covis, learned, out_dir, "V_max (frames)", progress=progress,
                 executor=executor, failures=failures)


def plot_figure(path: Path, results: dict[object, dict[str, Result]], x_label: str,
          bars: bool = False) -> None:
    """Mean υ (lost frame = 0) on the left, the share of lost frames beside it: a policy that
    buys a low υ by losing frames shows on the right."""
    plt = pyplot()
    fig, (ax, ax_lost) = plt.subplots(1, 2, figsize=(11, 4.2))
    xs = list(results)
    labels = list(next(iter(results.values())))
    for i, label in enumerate(labels):
        series = [results[x][label] for x in xs]
        style = ({"linestyle": "--", "color": "k"} if label == REFERENCE else
                 {"linestyle": ":", "color": "grey"} if label == BOUND else {})
        for axis, values, errs in ((ax, [r.mean for r in series], [r.ci95 for r in series]),
                                   (ax_lost, [100 * r.lost_share for r in series], None)):
            if bars:
                width = 0.8 / len(labels)
                axis.bar(np.arange(len(xs)) + i * width, values, width, yerr=errs, capsize=3,
                         label=label)
            else:
                axis.errorbar([float(x) for x in xs], values, yerr=errs,  # type: ignore[arg-type]
                              marker="o", capsize=3, label=label, **style)
    for axis in (ax, ax_lost):
        if bars:
            axis.set_xticks(np.arange(len(xs)) + 0.4 - 0.4 / len(labels), [str(x) for x in xs])
        axis.set_xlabel(x_label)
    ax.set_ylabel("mean υ, lost frame = 0 (lower is better)")
    ax_lost.set_ylabel("lost next-slot frames (%)")
    ax_lost.legend(fontsize=8, loc="center right")   # the left panel holds no free space
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
