"""Paper Figs 7–9: mean pose-estimation uncertainty υ of the learned and the rule-based
policies against the clairvoyant oracle, on held-out seeds (0, 1, … — training uses
``TRAINING_SEED_BASE`` + …, so no evaluated channel realisation or start frame was trained on).

* **fig7** — υ vs the share of high-rate slots of a 2-state chain (one interval).
* **fig8** — N = 2 vs N = 4 rate states at the same mean rate (doubly stochastic chains, whose
  stationary distribution is uniform: 60 Mbit/s on 40–80 for every N).
* **fig9** — υ vs V_max ∈ {25, …, 45} with a non-stationary chain: three intervals per episode.

A learned policy is given as ``label=CHECKPOINT``; each figure's CSV has one row per (x,
policy) with the mean, the 95 % confidence half-width (Student t over the runs) and the runs.
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


def _policies(learned: dict[str, Path], oracle: bool) -> tuple[list[str], dict[str, str]]:
    """Policy specs for ``evaluate`` and the label each result is shown with."""
    specs = [*RULES, *(f"mbrl:{path}" for path in learned.values())]
    labels = {name: name.upper() for name in RULES}
    labels.update({f"mbrl:{path}": f"Proposed ({label})" for label, path in learned.items()})
    if oracle:
        specs.append("oracle")
        labels["oracle"] = "Oracle (clairvoyant)"
    return specs, labels


def _run(dataset: CovisibilityDataset, channel: str, setting: Setting, learned: dict[str, Path],
         oracle: bool, progress: Progress | None) -> dict[str, PolicyResult]:
    specs, labels = _policies(learned, oracle)
    seeds = list(range(setting.seed0, setting.seed0 + setting.runs))
    config = SimConfig(vmax=setting.vmax, slots=setting.slots)
    out = {}
    for spec in specs:
        (res,) = evaluate([spec], dataset, channel, config, seeds, make_policy=make_policy)
        out[labels[spec]] = res
        if progress:
            progress(f"{channel} V_max {setting.vmax}: {labels[spec]} {res.mean:.1f} "
                     f"± {res.ci95:.1f}")
    return out


def sweep(name: str, xs: list[object], channel_of: Callable[[object], str],
          setting_of: Callable[[object], Setting], dataset: CovisibilityDataset,
          learned: dict[str, Path], out_dir: Path, x_label: str, oracle: bool = True,
          progress: Progress | None = None) -> dict[object, dict[str, PolicyResult]]:
    """Every policy at every x; writes ``{name}.csv`` and ``{name}.png``."""
    results = {x: _run(dataset, channel_of(x), setting_of(x), learned, oracle, progress)
               for x in xs}
    rows = [[x, label, r.mean, r.ci95, len(r.per_seed), r.lost_ratio]
            for x, by in results.items() for label, r in by.items()]
    write_csv(out_dir / f"{name}.csv",
              [x_label, "policy", "mean_uncertainty", "ci95", "runs", "lost_ratio"], rows)
    _plot(out_dir / f"{name}.png", results, x_label)
    return results


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
    rows = [[x, label, r.mean, r.ci95, len(r.per_seed), r.lost_ratio]
            for x, by in results.items() for label, r in by.items()]
    write_csv(out_dir / "fig8.csv", ["number of rate states N", "policy", "mean_uncertainty",
                                     "ci95", "runs", "lost_ratio"], rows)
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
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    xs = list(results)
    labels = list(next(iter(results.values())))
    for i, label in enumerate(labels):
        means = [results[x][label].mean for x in xs]
        errs = [results[x][label].ci95 for x in xs]
        style = {"linestyle": "--", "color": "k"} if label.startswith("Oracle") else {}
        if bars:
            width = 0.8 / len(labels)
            ax.bar(np.arange(len(xs)) + i * width, means, width, yerr=errs, capsize=3,
                   label=label)
        else:
            ax.errorbar([float(x) for x in xs], means, yerr=errs, marker="o", capsize=3,  # type: ignore[arg-type]
                        label=label, **style)
    if bars:
        ax.set_xticks(np.arange(len(xs)) + 0.4 - 0.4 / len(labels), [str(x) for x in xs])
    ax.set_xlabel(x_label)
    ax.set_ylabel("pose estimation uncertainty υ (lower is better)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
