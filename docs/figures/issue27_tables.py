"""The live tables of docs/results.md § "The map decides the device's tracking" (issue #27),
condensed from the files ``twinslam evaluate`` wrote (copied here as issue27-WALK-*.csv):
per scenario and policy the device's figures, then the paired differences with the best rule
policy on the device's failure share and ATE; and the offline yardstick: the simulator's lost
share on the live walk (issue27-sim-SCENARIO.csv, ``twinslam sim --csv``) beside the share the
live device failed.

    python docs/figures/issue27_tables.py 7scenes synthetic 7scenes-local
    python docs/figures/issue27_tables.py --yardstick
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: (summary.csv column stem, title, digits, scale)
COLUMNS = (("device_failure_share", "device failed (%)", 1, 100.0),
           ("predicted_lost_share", "predicted lost (%)", 1, 100.0),
           ("tracking_failures", "failures", 1, 1.0),
           ("relocalisations", "relocalisations", 1, 1.0),
           ("untracked_frames", "untracked frames", 0, 1.0), ("ate_m", "ATE (m)", 3, 1.0),
           ("mean_uncertainty", "mean υ", 0, 1.0), ("frames_uploaded", "uploads", 0, 1.0))
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
    for r in _rows(HERE / f"issue27-{walk}-summary.csv"):
        cells = [_cell(r[f"{c}_mean"], r[f"{c}_ci95"], d, s) for c, _, d, s in COLUMNS]
        lines.append(f"| {r['scenario']} | {r['policy']} | {r['runs']} | " + " | ".join(cells)
                     + " |")
    return "\n".join(lines)


def paired_table(walk: str) -> str:
    rows = [r for r in _rows(HERE / f"issue27-{walk}-paired.csv") if r["metric"] in PAIRED]
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
#: the simulator's policy column → the live table's label (the AMM runs pooled)
LIVE_LABEL = {"lff": "lff", "pu": "pu", "adapt": "adapt", "random": "random", "mbrl": "AMM"}


def yardstick_table() -> str:
    """Per scenario and policy: the simulator's lost share on the live walk (mean over seeds;
    a learned policy's training runs pooled) beside the live device's failure share."""
    live = {(r["scenario"], r["policy"]): float(r["device_failure_share_mean"])
            for r in _rows(HERE / "issue27-7scenes-summary.csv")}
    lines = ["| policy | " + " | ".join(f"{s}: simulator / device" for s in SCENARIOS) + " |",
             "|---|" + "---|" * len(SCENARIOS)]
    shares: dict[str, dict[str, list[float]]] = {}
    for scenario in SCENARIOS:
        for r in _rows(HERE / f"issue27-sim-{scenario}.csv"):
            label = LIVE_LABEL.get(r["spec"].partition(":")[0], r["spec"])
            shares.setdefault(label, {}).setdefault(scenario, []).append(float(r["lost_share"]))
    for label, by in shares.items():
        cells = []
        for scenario in SCENARIOS:
            sim = 100 * sum(by[scenario]) / len(by[scenario])
            dev = live.get((scenario, label))
            cells.append(f"{sim:.1f} / " + ("–" if dev is None else f"{100 * dev:.1f}"))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:] == ["--yardstick"]:
        print(yardstick_table())
        sys.exit()
    for walk in sys.argv[1:] or ["7scenes"]:
        print(f"### {walk}\n\n{summary_table(walk)}\n\n{paired_table(walk)}\n")
