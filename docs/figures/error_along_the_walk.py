"""Where along the walk a trajectory's error is: the distance between each tracked frame's
position and the truth (after the SE(3) alignment ATE uses — ATE is their RMS), by the
sequence's frame, on the way out and on the way back.

    .venv/bin/python docs/figures/error_along_the_walk.py [--png FILE] [--bin N] \\
        front-end=docs/figures/trajectory-error/front-end-585.csv \\
        paper-device=docs/figures/own-map/revisit-1000-short-loop-own-map ...

Each ``LABEL=PATH`` is either a ``twinslam evaluate`` folder (its calibration_frames.csv or
.csv.gz: every scored frame of every run, ``translation_error_m`` aligned run by run) or the
``--errors-csv`` of ``python -m bench.front_end_drift`` (one walk of the front end alone).
Prints one markdown table — per label and pass, the RMS error of the tracked frames in each
bin of ``--bin`` sequence frames, pooled over the runs, and over the whole pass — and with
``--png`` draws the same curves (a line a label and pass). A frame error that every seed of a
live device shares where the front end alone has it too is the front end's; one that varies
from seed to seed is what the map the device tracked against added.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from twinslam.live.calibration.report import read_rows
from twinslam.reporting import pyplot

#: (label, pass) → (sequence frame, error in metres) of every tracked frame
Errors = dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]


def _rows(path: Path) -> list[dict[str, str]]:
    """An evaluate folder's scored frames, or a front-end errors CSV's rows."""
    if not path.exists():
        raise SystemExit(f"{path}: neither a twinslam evaluate folder nor a "
                         "bench.front_end_drift --errors-csv")
    try:
        if path.is_dir():
            return read_rows([path], "calibration_frames.csv")
        return read_rows([path.parent], path.name)
    except FileNotFoundError as exc:
        raise SystemExit(str(exc)) from None


def read_errors(label: str, path: Path) -> Errors:
    """The tracked frames' errors of one evaluate folder or front-end errors CSV, by pass."""
    rows = _rows(path)
    out: dict[tuple[str, str], tuple[list[int], list[float]]] = {}
    if rows and "pass" in rows[0]:                           # bench.front_end_drift
        for r in rows:
            frames, errors = out.setdefault((label, r["pass"]), ([], []))
            frames.append(int(r["frame"]))
            errors.append(float(r["translation_error_m"]))
    else:                                                    # twinslam evaluate
        if not rows:
            raise SystemExit(f"{path}: no frames")
        played = max(int(r["frame_id"]) for r in rows) + 1
        for r in rows:
            error = float(r["translation_error_m"]) if r["translation_error_m"] else math.nan
            if r["device_tracked"] != "1" or not math.isfinite(error):
                continue
            way = "forward" if int(r["frame_id"]) < (played + 1) // 2 else "back"
            frames, errors = out.setdefault((label, way), ([], []))
            frames.append(int(r["row"]))
            errors.append(error)
    return {key: (np.array(f), np.array(e)) for key, (f, e) in out.items()}


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan


def table(errors: Errors, bin_frames: int) -> str:
    """Markdown: a row a label and pass, the RMS error (cm) of each bin of sequence frames."""
    last = max(int(f.max()) for f, _ in errors.values())
    edges = list(range(0, last + 1, bin_frames))
    head = ["label", "pass", "frames", "all"] + [f"{a}–{a + bin_frames - 1}" for a in edges]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for (label, way), (frames, err) in errors.items():
        cells = [f"{100 * rms(err[(frames >= a) & (frames < a + bin_frames)]):.1f}"
                 for a in edges]
        lines.append(f"| {label} | {way} | {err.size} | {100 * rms(err):.1f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def draw(errors: Errors, bin_frames: int, png: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    labels = list(dict.fromkeys(label for label, _ in errors))
    colours = plt.get_cmap("tab10")
    for (label, way), (frames, err) in errors.items():          # a colour a label, a style a pass
        starts = np.arange(0, int(frames.max()) + 1, bin_frames)
        curve = [100 * rms(err[(frames >= a) & (frames < a + bin_frames)]) for a in starts]
        ax.plot(starts + bin_frames / 2, curve, "-" if way == "forward" else "--",
                color=colours(labels.index(label) % 10), marker="o", markersize=3,
                label=f"{label}, {way}")
    ax.set_xlabel("sequence frame")
    ax.set_ylabel(f"RMS position error over {bin_frames} frames (cm)")
    ax.set_title("Where along the walk the trajectory error is (SE(3)-aligned, tracked frames)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="LABEL=PATH",
                        help="an evaluate folder or a bench.front_end_drift --errors-csv")
    parser.add_argument("--bin", type=int, default=100, help="sequence frames a bin")
    parser.add_argument("--png", type=Path, default=None, help="draw the curves here")
    args = parser.parse_args()
    if args.bin < 1:
        parser.error(f"--bin must be at least 1, got {args.bin}")
    errors: Errors = {}
    for item in args.inputs:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            parser.error(f"expected LABEL=PATH, got {item!r}")
        errors.update(read_errors(label, Path(path)))
    print(table(errors, args.bin))
    if args.png is not None:
        draw(errors, args.bin, args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
