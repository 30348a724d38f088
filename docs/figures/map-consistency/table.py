"""The map-consistency runs as tables: each run's figures from its log (the last lines
``python -m bench.map_consistency`` prints), the mean ± its 95 % half-width (Student's t) per
variant and the paired differences against a reference variant by seed.

    python docs/figures/map-consistency/table.py FOLDER [--reference NAME] [--csv FILE]

FOLDER holds logs named ``VARIANT-SEED.log``.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from twinslam.reporting import mean_ci95, paired_difference  # noqa: E402

FINAL = re.compile(r"(\d+) of (\d+) frames tracked, ATE ([\d.]+) m, revisit error RMS "
                   r"([\d.na]+) m .*loops (\d+) closed (\d+) refused")
LOOP = re.compile(r"measured off by ([\d.]+) m, ([\d.]+) deg")
KEYFRAMES = re.compile(r"final keyframes \(archive and map, (\d+)\): ATE ([\d.]+) m")
#: printed since the bench counted them (older logs: NaN; logs that counted every close
#: look-alike, before a pair one keyframe sees together was left out: no duplicate share)
OUTLIERS = re.compile(r"matches: ([\d.]+)% outliers")
DUPLICATES = re.compile(r"([\d.]+)% with a look-alike within \d+ cm no keyframe sees with it")
#: the device's poses moved with their keyframes' corrections since (printed since the bench
#: anchored them; older logs: NaN)
ANCHORED = re.compile(r"anchored to the keyframes .*: ATE ([\d.]+) m, revisit error RMS "
                      r"([\d.na]+) m")
#: the odom frame's largest step beyond the truth's (printed since the bench measured it)
ODOM = re.compile(r"the odom frame: its largest step beyond the truth's ([\d.]+) mm")
FIGURES = ("ate_m", "revisit_m", "anchored_ate_m", "anchored_revisit_m", "keyframe_ate_m",
           "untracked", "loops_closed", "loops_refused", "outlier_share", "duplicate_share",
           "odom_step_mm")
#: a seed counts as worse than the reference's when its revisit error is this much larger
WORSE_M = 0.005


def read_run(path: Path) -> dict[str, float] | None:
    """A run's figures, or None for a log that did not finish."""
    text = path.read_text()
    final, keyframes = FINAL.search(text), KEYFRAMES.search(text)
    if final is None or keyframes is None:
        return None
    tracked, frames, ate, revisit, closed, refused = final.groups()
    outliers, duplicates = (float(found.group(1)) / 100 if (found := pattern.search(text))
                            else float("nan") for pattern in (OUTLIERS, DUPLICATES))
    anchored, odom = ANCHORED.search(text), ODOM.search(text)
    anchored_ate, anchored_revisit = ((float(anchored.group(1)), float(anchored.group(2)))
                                      if anchored else (float("nan"), float("nan")))
    return {"ate_m": float(ate), "revisit_m": float(revisit),
            "anchored_ate_m": anchored_ate, "anchored_revisit_m": anchored_revisit,
            "keyframe_ate_m": float(keyframes.group(2)),
            "untracked": float(int(frames) - int(tracked)), "loops_closed": float(closed),
            "loops_refused": float(refused), "outlier_share": outliers,
            "duplicate_share": duplicates,
            "odom_step_mm": float(odom.group(1)) if odom else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, help="the logs, VARIANT-SEED.log")
    parser.add_argument("--reference", help="the variant the others are paired against")
    parser.add_argument("--csv", type=Path, help="write every run's figures here")
    parser.add_argument("--loop-errors", action="store_true",
                        help="also each variant's loop measurements against the truth (the "
                        "logs' 'measured off by' lines): median, 95th percentile and largest")
    args = parser.parse_args()
    runs: dict[str, dict[int, dict[str, float]]] = {}
    for log in sorted(args.folder.glob("*.log")):
        variant, _, seed = log.stem.rpartition("-")
        figures = read_run(log)
        if figures is not None:
            runs.setdefault(variant, {})[int(seed)] = figures
    if args.csv:
        with args.csv.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["variant", "seed", *FIGURES])
            for variant, by_seed in runs.items():
                for seed, fig in sorted(by_seed.items()):
                    writer.writerow([variant, seed, *(fig[k] for k in FIGURES)])
    print("| variant | runs | ATE (m) | revisit error (m) | anchored: ATE (m) | anchored: "
          "revisit error (m) | the edge's final keyframes, ATE (m) "
          "| untracked frames | loops closed | loops refused | the device's outliers | "
          "map points with a look-alike | odom step beyond the truth's (mm) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for variant, by_seed in runs.items():
        cells = []
        for key in FIGURES:
            mean, half = mean_ci95([fig[key] for fig in by_seed.values()])
            if not np.isfinite(mean):
                cells.append("not counted")
                continue
            if key.endswith("_share"):
                cells.append(f"{mean:.1%} ± {half:.1%}")
                continue
            digits = 3 if key.endswith("_m") else 1
            cells.append(f"{mean:.{digits}f} ± {half:.{digits}f}")
        print(f"| {variant} | {len(by_seed)} | " + " | ".join(cells) + " |")
    if args.loop_errors:
        print_loop_errors(args.folder)
    if not args.reference or args.reference not in runs:
        return
    print()
    print(f"| variant − {args.reference}, paired by seed | seeds | ATE (m) | revisit error (m) | "
          "anchored: ATE (m) | anchored: revisit error (m) | final keyframes, ATE (m) | "
          f"the device's outliers | seeds worse by > {WORSE_M * 100:g} cm: revisit error as "
          "published / anchored |")
    print("|---|---|---|---|---|---|---|---|---|")
    base = runs[args.reference]
    for variant, by_seed in runs.items():
        if variant == args.reference:
            continue
        seeds = sorted(set(by_seed) & set(base))
        cells = []
        for key in ("ate_m", "revisit_m", "anchored_ate_m", "anchored_revisit_m",
                    "keyframe_ate_m", "outlier_share"):
            d = paired_difference([[by_seed[s][key] for s in seeds]],
                                  [base[s][key] for s in seeds])
            if not np.isfinite(d.mean):
                cells.append("not counted")
            elif key.endswith("share"):
                cells.append(f"{d.mean:+.1%} [{d.low:+.1%}, {d.high:+.1%}]")
            else:
                cells.append(f"{d.mean:+.3f} [{d.low:+.3f}, {d.high:+.3f}]")
        worse = [sum(by_seed[s][key] > base[s][key] + WORSE_M for s in seeds)
                 for key in ("revisit_m", "anchored_revisit_m")]
        cells.append(f"{worse[0]} / {worse[1]}")
        print(f"| {variant} | {len(seeds)} | " + " | ".join(cells) + " |")


def print_loop_errors(folder: Path) -> None:
    """Each variant's loops (every run's) against the truth's relative pose."""
    errors: dict[str, list[tuple[float, float]]] = {}
    for log in sorted(folder.glob("*.log")):
        variant = log.stem.rpartition("-")[0]
        errors.setdefault(variant, []).extend(
            (float(m), float(d)) for m, d in LOOP.findall(log.read_text()))
    print()
    print("| variant | loops measured | off (m): median / p95 / largest | off (°): median / p95 / "
          "largest | over 1° |")
    print("|---|---|---|---|---|")
    for variant, found in errors.items():
        if not found:
            continue
        metres, degrees = (np.array(column) for column in zip(*found, strict=True))
        cells = [" / ".join(f"{f(x):.3f}" for f in (np.median, lambda v: np.percentile(v, 95),
                                                     np.max)) for x in (metres, degrees)]
        print(f"| {variant} | {len(found)} | {cells[0]} | {cells[1]} | "
              f"{int(np.sum(degrees > 1.0))} |")


if __name__ == "__main__":
    main()
