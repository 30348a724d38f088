"""Paper Figs 7–9: mean pose-estimation uncertainty υ of the learned and the rule-based
policies beside the clairvoyant reference plan (a search, not a bound), on held-out seeds
(0, 1, … — training uses ``TRAINING_SEED_BASE`` + …, so no evaluated channel realisation or
start frame was trained on).

* **fig7** — υ vs the share of high-rate slots of a 2-state chain (one interval).
* **fig8** — N = 2 vs N = 4 rate states at the same mean rate (doubly stochastic chains, whose
  stationary distribution is uniform: 60 Mbit/s on 40–80 for every N).
* **fig9** — υ vs V_max ∈ {25, …, 45} with a non-stationary chain: three intervals per episode.

A learned policy is given as ``label=CHECKPOINT``; each figure's CSV has one row per (x,
policy) with mean υ (a lost frame scoring 0), its 95 % confidence half-width (Student t over
the runs), the runs, the share of lost next-slot frames and υ over the tracked frames.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.common import table1
from twinslam.common.reporting import pyplot, write_csv
from twinslam.policy_registry import make_policy
from twinslam.simulator.covisibility import CovisibilityDataset
from twinslam.simulator.env import SimConfig
from twinslam.simulator.evaluation import PolicyResult, evaluate

Progress = Callable[[str], None]
RULES = ("lff", "pu", "adapt")


@dataclass(frozen=True)
class Setting:
    runs: int = 15
    slots: int = 200
    vmax: int = table1.VMAX
    seed0: int = 0


def _policies(learned: dict[str, Path], reference: bool) -> tuple[list[str], dict[str, str]]:
    """Policy specs for ``evaluate`` and the label each result is shown with."""
    specs = [*RULES, *(f"mbrl:{path}" for path in learned.values())]
    labels = {name: name.upper() for name in RULES}
    labels.update({f"mbrl:{path}": f"Proposed ({label})" for label, path in learned.items()})
    if reference:
        specs.append("reference")
        labels["reference"] = "Reference (clairvoyant search)"
    return specs, labels


def _run(dataset: CovisibilityDataset, channel: str, setting: Setting, learned: dict[str, Path],
         reference: bool, progress: Progress | None) -> dict[str, PolicyResult]:
    specs, labels = _policies(learned, reference)
    seeds = list(range(setting.seed0, setting.seed0 + setting.runs))
    config = SimConfig(vmax=setting.vmax, slots=setting.slots)
    out = {}
    for spec in specs:
        seeded = [spec] if spec != "reference" else specs   # the reference starts from all
        res = evaluate(seeded, dataset, channel, config, seeds, make_policy=make_policy)[-1]
        out[labels[spec]] = res
        if progress:
            progress(f"{channel} V_max {setting.vmax}: {labels[spec]} {res.mean:.1f} "
                     f"± {res.ci95:.1f}, lost {res.lost_ratio:.1%}, tracked "
                     f"{res.mean_tracked:.1f}")
    return out


def sweep(name: str, xs: list[object], channel_of: Callable[[object], str],
          setting_of: Callable[[object], Setting], dataset: CovisibilityDataset,
          learned: dict[str, Path], out_dir: Path, x_label: str, reference: bool = True,
          progress: Progress | None = None) -> dict[object, dict[str, PolicyResult]]:
    """Every policy at every x; writes ``{name}.csv`` and ``{name}.png``."""
    results = {x: _run(dataset, channel_of(x), setting_of(x), learned, reference, progress)
               for x in xs}
    write_csv(out_dir / f"{name}.csv", [x_label, *COLUMNS], _rows(results))
    _plot(out_dir / f"{name}.png", results, x_label)
    return results


COLUMNS = ["policy", "mean_uncertainty", "ci95", "runs", "lost_share", "tracked_uncertainty"]


def _rows(results: dict[object, dict[str, PolicyResult]]) -> list[list[object]]:
    return [[x, label, r.mean, r.ci95, len(r.per_seed), r.lost_ratio, r.mean_tracked]
            for x, by in results.items() for label, r in by.items()]


def fig7(dataset: CovisibilityDataset, learned: dict[str, Path], out_dir: Path,
         setting: Setting = Setting(), ratios: tuple[float, ...] = (0.2, 0.35, 0.5, 0.65, 0.8),
         progress: Progress | None = None) -> dict[object, dict[str, PolicyResult]]:
    return sweep("fig7", list(ratios), lambda r: f"markov:N=2,ratio={r}", lambda _r: setting,
                 dataset, learned, out_dir, "ratio of high-rate slots", progress=progress)


def fig8(dataset: CovisibilityDataset, learned: dict[int, dict[str, Path]], out_dir: Path,
         setting: Setting = Setting(), progress: Progress | None = None
         ) -> dict[object, dict[str, PolicyResult]]:
    """``learned`` per N: each N has its own trained policies (the state's one-hot rate
    history has N columns)."""
    results: dict[object, dict[str, PolicyResult]] = {}
    for n, policies in learned.items():
        results.update(sweep(f"fig8_n{n}", [n], lambda m: f"markov:N={m},balanced",
                             lambda _m: setting, dataset, policies, out_dir,
                             "number of rate states N", progress=progress))
    write_csv(out_dir / "fig8.csv", ["number of rate states N", *COLUMNS], _rows(results))
    _plot(out_dir / "fig8.png", results, "number of rate states N", bars=True)
    return results


def fig9(dataset: CovisibilityDataset, learned: dict[str, Path], out_dir: Path,
         setting: Setting = Setting(), vmaxes: tuple[int, ...] = (25, 30, 35, 40, 45),
         progress: Progress | None = None) -> dict[object, dict[str, PolicyResult]]:
    interval = max(1, setting.slots // 3)
    return sweep("fig9", list(vmaxes), lambda _v: f"markov:N=2,K={interval},nonstationary",
                 lambda v: Setting(setting.runs, setting.slots, int(v), setting.seed0),  # type: ignore[arg-type]
                 dataset, learned, out_dir, "V_max (frames)", progress=progress)


def _plot(path: Path, results: dict[object, dict[str, PolicyResult]], x_label: str,
          bars: bool = False) -> None:
    """Mean υ (lost frame = 0) on the left, the share of lost frames beside it: a policy that
    buys a low υ by losing frames shows on the right."""
    plt = pyplot()
    fig, (ax, ax_lost) = plt.subplots(1, 2, figsize=(11, 4.2))
    xs = list(results)
    labels = list(next(iter(results.values())))
    for i, label in enumerate(labels):
        series = [results[x][label] for x in xs]
        style = {"linestyle": "--", "color": "k"} if label.startswith("Reference") else {}
        for axis, values, errs in ((ax, [r.mean for r in series], [r.ci95 for r in series]),
                                   (ax_lost, [100 * r.lost_ratio for r in series], None)):
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
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
