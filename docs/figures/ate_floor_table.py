"""The table of ``python -m bench.ate_floor --csv`` files side by side: per camera and walk
length, each stage's keyframe ATE and how well its poses explain the images.

    .venv/bin/python docs/figures/ate_floor_table.py \\
        "colour, 525 px (registered)|1000=docs/figures/ate-floor/colour-camera-1000.csv" ...

Each argument is ``CAMERA|FRAMES=CSV``: the label of the camera, the frames the walk played,
and the bench's CSV. Prints one markdown table, the label on each CSV's first row. With
``--anchored``, the stages scored as anchored content is instead (the revisit, nearby and
close pairs' RMS error, and the nearby pairs weighed as every frame's are; the files of a
bench run since 2026-12-02 have them): how far two devices holding each stage's poses would
disagree against this ground truth.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

COLUMNS = ["stage", "keyframes", "observations", "keyframe_ate_m", "median_reprojection_px",
           "within_3px"]
#: the anchored errors' columns (``--anchored``)
ANCHORED = ["revisit_rms_m", "nearby_rms_m", "close_rms_m", "frames_mix_rms_m"]


def read_stages(path: Path, columns: list[str] = COLUMNS) -> list[dict[str, str]]:
    """The stages of one bench CSV with ``columns``; SystemExit naming the file where it is
    not one (or one written before the bench had them)."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise SystemExit(f"{path}: {exc.strerror}") from exc
    if not rows or not set(columns) <= set(rows[0]):
        raise SystemExit(f"{path}: not a bench.ate_floor --csv file (columns "
                         f"{', '.join(columns)})")
    return rows


def table(inputs: list[tuple[str, str, Path]]) -> str:
    """The markdown table of ``(camera, frames, csv)`` inputs, in their order."""
    lines = ["| camera | frames | stage | keyframes | keyframe ATE (m) | median reprojection "
             "(px) | within 3 px |", "|---|---|---|---|---|---|---|"]
    for camera, frames, path in inputs:
        for i, row in enumerate(read_stages(path)):
            ate = f"{float(row['keyframe_ate_m']):.3f}" if row["keyframe_ate_m"] else "—"
            label = (camera, frames) if i == 0 else ("", "")
            lines.append(f"| {label[0]} | {label[1]} | {row['stage']} | {row['keyframes']} | "
                         f"{ate} | {float(row['median_reprojection_px']):.2f} | "
                         f"{100 * float(row['within_3px']):.1f} % |")
    return "\n".join(lines)


def anchored_table(inputs: list[tuple[str, str, Path]]) -> str:
    """The markdown table of the stages' anchored errors, in cm (the stages scored against
    the truth: the truth's own stage has none)."""
    lines = ["| camera | frames | stage | keyframe ATE (cm) | revisit RMS (cm) | nearby RMS "
             "(cm) | close RMS (cm) | nearby at the frames' mix (cm) |",
             "|---|---|---|---|---|---|---|---|"]
    for camera, frames, path in inputs:
        rows = [r for r in read_stages(path, COLUMNS + ANCHORED) if r["keyframe_ate_m"]]
        for i, row in enumerate(rows):
            label = (camera, frames) if i == 0 else ("", "")
            cells = " | ".join(f"{100 * float(row[c]):.1f}" if row[c] else "—"
                               for c in ["keyframe_ate_m", *ANCHORED])
            lines.append(f"| {label[0]} | {label[1]} | {row['stage']} | {cells} |")
    return "\n".join(lines)


def parse(arg: str) -> tuple[str, str, Path]:
    """``CAMERA|FRAMES=CSV`` as (camera, frames, path)."""
    label, sep, path = arg.partition("=")
    camera, bar, frames = label.rpartition("|")
    if not sep or not bar or not camera or not frames.isdigit() or not path:
        raise argparse.ArgumentTypeError(f"{arg!r}: expected CAMERA|FRAMES=CSV")
    return camera, frames, Path(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", type=parse, metavar="CAMERA|FRAMES=CSV",
                        help="a camera's label, the walk's frames and a bench.ate_floor CSV")
    parser.add_argument("--anchored", action="store_true",
                        help="the stages' revisit, nearby and close errors instead (pairs of "
                        "keyframes within 0.3 m and 20°: ≥ 10 s apart, any, under 1 s apart; "
                        "and the nearby pairs weighed as every frame's)")
    args = parser.parse_args(argv)
    print(anchored_table(args.inputs) if args.anchored else table(args.inputs))


if __name__ == "__main__":
    main()
