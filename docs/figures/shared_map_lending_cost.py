"""What lending costs the device that borrows (docs/results/shared-map.md, "What the device's
own map did"): slot by slot, how many points of the map it held the second device tracked
each frame on — alone, lent, lent with covered frames left out — and how far the first
device's lent keyframes stand from the second device's own keyframes of the same frames.

Reads ``bench.shared_map``'s ``--frames-csv`` and ``--keyframes-csv`` of one seed's runs
(``docs/figures/shared-map/point-index/seed2-{alone,lent,covered}-{frames,keyframes}.csv``,
the commands are on the page), prints the slot table and the keyframe offsets and draws
``docs/figures/shared-map/point-index/lending-cost.png``.

    .venv/bin/python docs/figures/shared_map_lending_cost.py [--runs PREFIX]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from twinslam.reporting import pyplot
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS

HERE = Path(__file__).resolve().parent / "shared-map" / "point-index"
CONDITIONS = ("alone", "lent", "covered")
#: frames a slot of the default device (1 s at 30 Hz)
SLOT_FRAMES = 30


def frames(prefix: Path, condition: str, device: str = "second") -> np.ndarray:
    """(frame, map points) of the device's tracked frames on a map (version > 0)."""
    with Path(f"{prefix}-{condition}-frames.csv").open(encoding="utf-8") as fh:
        rows = [(int(r["frame"]), int(r["map_points"])) for r in csv.DictReader(fh)
                if r["device"] == device and int(r["tracked"]) and int(r["map_version"]) > 0]
    return np.array(rows, dtype=np.int64).reshape(-1, 2)


def offsets(prefix: Path, condition: str) -> list[tuple[int, float]]:
    """(frame, cm) between the lent copy and the second device's own keyframe of one frame,
    in the second device's edge map at the end."""
    own, lent = {}, {}
    with Path(f"{prefix}-{condition}-keyframes.csv").open(encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            if r["device"] == "second":
                xyz = np.array([float(r["x"]), float(r["y"]), float(r["z"])])
                (lent if r["lent"] == "1" else own)[int(r["frame"])] = xyz
    return [(f, float(np.linalg.norm(own[f] - lent[f]) * 100)) for f in sorted(own.keys()
                                                                               & lent.keys())]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=HERE / "seed2",
                        help="the runs' file prefix (default: %(default)s)")
    args = parser.parse_args()
    by = {c: frames(args.runs, c) for c in CONDITIONS}
    slots = sorted({int(f) // SLOT_FRAMES for a in by.values() for f in a[:, 0]})
    print("| the walk's frames | " + " | ".join(
        f"{c}: map points (median) / frames under {MIN_INLIERS}" for c in CONDITIONS) + " |")
    print("|---|" + "---|" * len(CONDITIONS))
    medians = {c: [] for c in CONDITIONS}
    for s in slots:
        cells = []
        for c in CONDITIONS:
            a = by[c][by[c][:, 0] // SLOT_FRAMES == s, 1]
            medians[c].append(float(np.median(a)) if len(a) else np.nan)
            cells.append(f"{np.median(a):.0f} / {(a < MIN_INLIERS).sum()}" if len(a) else "–")
        print(f"| {s * SLOT_FRAMES}–{s * SLOT_FRAMES + SLOT_FRAMES - 1} | " + " | ".join(cells)
              + " |")
    gaps = offsets(args.runs, "lent")
    print("\nthe lent copy against the second device's own keyframe of a frame (lent run): "
          + ", ".join(f"{f}: {cm:.1f} cm" for f, cm in gaps))

    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    colours = {"alone": "#888888", "lent": "#7fa7d9", "covered": "#1f5fae"}
    x = [s * SLOT_FRAMES for s in slots]
    for c in CONDITIONS:
        top.plot(x, medians[c], marker="o", ms=3, label=c, color=colours[c])
    top.axhline(MIN_INLIERS, color="#c03030", lw=0.8, ls="--", label=f"{MIN_INLIERS} points")
    top.set_yscale("log")
    top.set_ylabel("map points a frame\n(median a slot)")
    top.legend(fontsize=8, ncol=4)
    bottom.plot([f for f, _ in gaps], [cm for _, cm in gaps], marker="s", ms=3,
                color="#1f5fae")
    bottom.set_ylabel("lent copy − own\nkeyframe, cm")
    bottom.set_xlabel("the walk's frame (the second device's)")
    fig.tight_layout()
    out = args.runs.parent / "lending-cost.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
