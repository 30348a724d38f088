"""The README's table of the default-device sweep: per device variant, over every run of every
uplink family of ``docs/figures/default-device/VARIANT-1000/runs.csv`` (the whole
``revisit-v15`` walk), the figures a user judges a device by — the failed share of played
frames (mean, and the worst run), the runs whose largest aligned error passed 0.3 m, jumps, the
ATE, the revisit error (as published / anchored to the edge's final keyframes, where the runs
measured it; a device whose keyframes never moved once in the map — no loops, no bundle
adjustment — has its anchored revisit error equal to its published one), the jitter of the
published position against the truth's, the device's CPU a frame and the camera frames
dropped. Means are over runs; every family weighs the same (the same seeds each).

    .venv/bin/python docs/figures/default_device_summary.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from twinslam.live.runs import anchored_as_published

SWEEP = Path(__file__).resolve().parent / "default-device"
#: (folder, what the README calls it); FIXED: the variants whose keyframes never moved
VARIANTS = (("loops-fusion-1000", "**default**: edge+local, 1 s slots, restores, no local "
             "bundle adjustment at the edge, fusion on integration, loop closing"),
            ("no-adjustment-1000", "the default before: the same without fusion on integration "
             "and loop closing"),
            ("edge-local-1000", "the default before that: with the edge's local bundle "
             "adjustment (5 keyframes)"),
            ("short-loop-own-map-1000", "tuned paper device: edge, 1 s slots, restores, own "
             "points when lost"),
            ("table-i-1000", "Table I's device: edge, 2 s slots"))
FIXED = frozenset({"no-adjustment-1000"})


def _runs(folder: Path) -> list[dict[str, str]]:
    with (folder / "runs.csv").open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _mean(rows: list[dict[str, str]], column: str) -> float:
    return sum(float(r[column]) for r in rows) / len(rows)


def _mean_or_dash(rows: list[dict[str, str]], column: str) -> str:
    """The mean of a column the runs may predate, in metres to the millimetre; "–" without."""
    return f"{_mean(rows, column):.3f}" if column in rows[0] else "–"


def table(sweep: Path = SWEEP) -> list[str]:
    """The Markdown lines of the table."""
    lines = ["| device | runs | failed frames (mean / worst run) | runs with an error > 0.3 m "
             "| jumps | ATE (m) | revisit error (m; published / anchored) | jitter RMS (mm; "
             "truth) | device CPU (ms/frame) | dropped |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for folder, name in VARIANTS:
        rows = _runs(sweep / folder)
        if folder in FIXED:
            try:
                rows = anchored_as_published(rows, folder)
            except ValueError as exc:
                raise SystemExit(str(exc)) from None
        worst = max(float(r["failed_share"]) for r in rows)
        over = sum(float(r["max_error_m"]) > 0.3 for r in rows)
        jumps = sum(float(r["jumps"]) for r in rows)
        dropped = sum(int(float(r["frames_dropped"])) for r in rows)
        lines.append(f"| {name} | {len(rows)} | {_mean(rows, 'failed_share'):.1%} / "
                     f"{worst:.1%} | {over} | {jumps:.0f} | {_mean(rows, 'ate_m'):.3f} | "
                     f"{_mean_or_dash(rows, 'revisit_error_m')} / "
                     f"{_mean_or_dash(rows, 'anchored_revisit_error_m')} | "
                     f"{_mean(rows, 'jitter_rms_mm'):.1f} "
                     f"({_mean(rows, 'truth_jitter_rms_mm'):.1f}) | "
                     f"{_mean(rows, 'device_cpu_ms'):.1f} | {dropped} |")
    return lines


def main(argv: list[str]) -> int:
    sweep = Path(argv[0]) if argv else SWEEP
    print("\n".join(table(sweep)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
