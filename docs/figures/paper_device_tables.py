"""The live tables of docs/results/paper-device.md, "The map decides the device's tracking",
condensed from the files ``twinslam evaluate`` wrote (copied here as paper-device/WALK-*.csv):
per scenario and policy the device's figures, then the paired differences with the best rule
policy on the device's failure share and ATE; and the offline yardstick: the simulator's lost
share, mean υ and υ tracked on the live walk (paper-device/sim-SCENARIO.csv, ``twinslam sim
--csv``) beside the share the live device failed.

    .venv/bin/python docs/figures/paper_device_tables.py 7scenes synthetic 7scenes-local
    .venv/bin/python docs/figures/paper_device_tables.py --yardstick
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

from twinslam.reporting import mean_ci95

HERE = Path(__file__).resolve().parent
#: (summary.csv column stem, title, digits, scale)
COLUMNS = (("device_failure_share", "device failed (%)", 1, 100.0),
           ("predicted_lost_share", "predicted lost (%)", 1, 100.0),
           ("tracking_failures", "failures", 1, 1.0),
           ("relocalisations", "relocalisations", 1, 1.0),
           ("untracked_frames", "untracked frames", 0, 1.0), ("ate_m", "ATE (m)", 3, 1.0),
           # the edge's MapStats, the three figures of docs/architecture.md §2 together
           ("mean_uncertainty", "mean υ", 0, 1.0), ("lost_share", "lost share (%)", 1, 100.0),
           ("tracked_uncertainty", "υ tracked", 0, 1.0), ("frames_uploaded", "uploads", 0, 1.0))
PAIRED = {"device_failure_share": ("device failed (pts)", 1, 100.0),
          "ate_m": ("ATE (m)", 3, 1.0), "untracked_frames": ("untracked frames", 0, 1.0)}


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _cell(mean: str, half: str, digits: int, scale: float) -> str:
    m, h = float(mean) * scale, float(half) * scale
    if math.isnan(m):
        return "–"
    return f"{m:.{digits}f}" + ("" if math.isnan(h) else f" ± {h:.{digits}f}")


def summary_table(walk: str) -> str:
    lines = ["| scenario | policy | runs | " + " | ".join(t for _, t, _, _ in COLUMNS) + " |",
             "|---|---|---|" + "---|" * len(COLUMNS)]
    for r in _rows(HERE / f"paper-device/{walk}-summary.csv"):
        cells = [_cell(r[f"{c}_mean"], r[f"{c}_ci95"], d, s) for c, _, d, s in COLUMNS]
        lines.append(f"| {r['scenario']} | {r['policy']} | {r['runs']} | " + " | ".join(cells)
                     + " |")
    return "\n".join(lines)


def paired_table(walk: str) -> str:
    rows = [r for r in _rows(HERE / f"paper-device/{walk}-paired.csv") if r["metric"] in PAIRED]
    lines = ["| scenario | figure | best rule policy | policy | seeds | policy − best |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        title, digits, scale = PAIRED[r["metric"]]
        d, h = float(r["difference"]) * scale, float(r["ci95"]) * scale
        mark = " **(CI excludes 0)**" if abs(d) > h else ""
        lines.append(f"| {r['scenario']} | {title} | {r['best']} | {r['policy']} | "
                     f"{r['seeds']} | {d:+.{digits}f} ± {h:.{digits}f}{mark} |")
    return "\n".join(lines)


SCENARIOS = ("revisit-v15", "revisit-v25", "constrained", "outages")
def yardstick_table() -> str:
    """Per scenario and policy: the simulator's mean υ, lost share and υ over tracked frames on
    the live walk (mean over seeds; each training run of the learned policy on its own row)
    beside the live device's failure share of the same policy or training run (mean over
    seeds; a seed whose every frame was lost has no υ tracked and is left out of that mean)."""
    live_runs: dict[tuple[str, str], list[float]] = {}
    for r in _rows(HERE / "paper-device/7scenes-calibration.csv"):
        live_runs.setdefault((r["scenario"], r["spec"] or r["policy"]), []).append(
            float(r["device_failure_share"]))
    live = {key: mean_ci95(values)[0] for key, values in live_runs.items()}
    lines = ["| scenario | policy | simulator: mean υ | lost (%) | υ tracked | live device "
             "failed (%) |", "|---|---|---|---|---|---|"]
    for scenario in SCENARIOS:
        runs: dict[str, list[dict[str, str]]] = {}
        for r in _rows(HERE / f"paper-device/sim-{scenario}.csv"):
            kind, _, path = r["spec"].partition(":")
            label = f"AMM ({Path(path).stem})" if kind == "mbrl" else r["spec"]
            runs.setdefault(label, []).append(r)
        for label, rows in runs.items():
            mean = {c: mean_ci95([float(r[c]) for r in rows])[0]     # NaN seeds left out
                    for c in ("mean_uncertainty", "lost_share", "tracked_uncertainty")}
            dev = live.get((scenario, rows[0]["spec"]))
            lines.append(f"| {scenario} | {label} | {mean['mean_uncertainty']:.1f} | "
                         f"{100 * mean['lost_share']:.1f} | {mean['tracked_uncertainty']:.1f} | "
                         + ("–" if dev is None else f"{100 * dev:.1f}") + " |")
    return "\n".join(lines)


def training_runs_table(walk: str) -> str:
    """The learned policy live, one row per training run (the summary pools them): the
    device's failure share and ATE, mean ± 95 % CI over seeds."""
    failed = {(r["scenario"], r["spec"], r["seed"]): float(r["device_failure_share"])
              for r in _rows(HERE / f"paper-device/{walk}-calibration.csv")}
    runs: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for r in _rows(HERE / f"paper-device/{walk}-runs.csv"):
        if r["spec"].startswith("mbrl:"):
            key = (r["scenario"], r["spec"])
            runs.setdefault(key, []).append((failed[(*key, r["seed"])], float(r["ate_m"])))
    lines = ["| scenario | training run | runs | device failed (%) | ATE (m) |",
             "|---|---|---|---|---|"]
    for (scenario, spec), values in runs.items():
        f_mean, f_half = mean_ci95([100 * f for f, _ in values])
        a_mean, a_half = mean_ci95([a for _, a in values])
        lines.append(f"| {scenario} | {Path(spec.partition(':')[2]).stem} | {len(values)} | "
                     f"{f_mean:.1f} ± {f_half:.1f} | {a_mean:.3f} ± {a_half:.3f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:] == ["--yardstick"]:
        print(yardstick_table())
        sys.exit()
    for walk in sys.argv[1:] or ["7scenes"]:
        print(f"### {walk}\n\n{summary_table(walk)}\n\n{paired_table(walk)}\n")
        if walk != "7scenes-local":
            print(f"{training_runs_table(walk)}\n")
