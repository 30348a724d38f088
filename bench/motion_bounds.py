"""How a camera really moves, beside the motion gate's bounds: the evidence the defaults of
:class:`twinslam.slam.pose_plausibility.MotionBounds` rest on.

    python -m bench.motion_bounds [SEQUENCE ...] [--frames 1000] [--colour-intrinsics FILE]
        [--csv FILE]

For each sequence with ground truth it prints the true motion between frames — the step (m),
the turn (°) and the speed over the gate's half-second window (m/s), their 99th percentile
and maximum — and how many times over that maximum each bound lies. Then the front end tracks
the sequence forward with the gate on (the device's tracker, a map of its own, as
``bench.front_end_drift`` runs it) and the same figures are printed for its tracked poses,
with the frames the gate refused: on a walk the tracker follows that count must be 0, or the
bounds are too tight for that camera. A sequence that is no dataset folder is a synthetic
world (``synthetic``, ``synthetic-corridor``).
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bench.frames import frame_at, random_access
from bench.paths import REPO, SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.rotations import rotation_angle_deg
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.tracking import Tracking, TrackingConfig
from twinslam.slam.pose_plausibility import MotionBounds

COLOUR_INTRINSICS = REPO / "config" / "7scenes-colour-intrinsics.txt"


@dataclass
class MotionFigures:
    """The motion of one pose track: per frame, the step and the turn, and the speed over
    the gate's window; the 99th percentile and the largest of each."""

    sequence: str
    source: str                     #: "truth" or "tracked"
    frames: int
    step_p99_m: float
    step_max_m: float
    turn_p99_deg: float
    turn_max_deg: float
    speed_p99_m_s: float
    speed_max_m_s: float
    refused: int = 0                #: frames the motion gate refused (tracked only)


def motion_figures(sequence: str, source: str, poses: Mapping[int, np.ndarray],
                   bounds: MotionBounds, frame_rate_hz: float, refused: int = 0
                   ) -> MotionFigures:
    """The figures of ``poses`` (frame index → camera-to-world), consecutive frames only."""
    steps, turns, speeds = [], [], []
    for i in sorted(poses):
        if i - 1 in poses:
            a, b = poses[i - 1], poses[i]
            steps.append(float(np.linalg.norm(b[:3, 3] - a[:3, 3])))
            turns.append(rotation_angle_deg(a[:3, :3].T @ b[:3, :3]))
        earlier = i - bounds.speed_window + 1
        if earlier in poses:
            moved = float(np.linalg.norm(poses[i][:3, 3] - poses[earlier][:3, 3]))
            speeds.append(moved / ((i - earlier) / frame_rate_hz))

    def p99_max(values: Sequence[float]) -> tuple[float, float]:
        return ((float(np.percentile(values, 99)), float(np.max(values))) if values
                else (float("nan"), float("nan")))

    return MotionFigures(sequence, source, len(poses), *p99_max(steps), *p99_max(turns),
                         *p99_max(speeds), refused)


def measure(sequence: str, frames: int, colour_intrinsics: str | None, bounds: MotionBounds,
            frame_rate_hz: float) -> list[MotionFigures]:
    """The truth's and the front end's figures for ``frames`` of ``sequence``."""
    reader = random_access(open_sequence(sequence, 0, frames, colour_intrinsics), sequence)
    tracking = Tracking(reader.intrinsics, TrackingConfig(relocalise=True, motion=bounds,
                                                          frame_rate_hz=frame_rate_hz))
    truth: dict[int, np.ndarray] = {}
    tracked: dict[int, np.ndarray] = {}
    refused = 0
    for index in range(len(reader)):
        frame = frame_at(reader, index, sequence)
        if frame.pose is not None:
            truth[index] = frame.pose
        out = tracking.track(frame.color, frame.depth)
        refused += bool(out.implausible)
        if out.tracked:
            tracked[index] = out.pose
        if index % 250 == 0:
            print(f"  {sequence}: frame {index}/{len(reader)}", flush=True)
    name = Path(sequence).name or sequence
    return [motion_figures(name, "truth", truth, bounds, frame_rate_hz),
            motion_figures(name, "tracked", tracked, bounds, frame_rate_hz, refused)]


def print_table(rows: list[MotionFigures], bounds: MotionBounds) -> None:
    print(f"{'sequence':<26} {'poses':<8} {'frames':>6} {'step p99':>9} {'max m':>7} "
          f"{'turn p99':>9} {'max °':>7} {'speed p99':>9} {'max m/s':>8} {'refused':>7}")
    for r in rows:
        print(f"{r.sequence:<26} {r.source:<8} {r.frames:>6d} {r.step_p99_m:>9.4f} "
              f"{r.step_max_m:>7.4f} {r.turn_p99_deg:>9.2f} {r.turn_max_deg:>7.2f} "
              f"{r.speed_p99_m_s:>9.3f} {r.speed_max_m_s:>8.3f} {r.refused:>7d}")
    print(f"bounds: step {bounds.max_step_m} m, turn {bounds.max_turn_deg}°, speed "
          f"{bounds.max_speed_m_s} m/s over {bounds.speed_window} frames")
    for r in rows:
        if r.source == "truth" and r.frames > 1:
            print(f"  {r.sequence}: the bounds lie {bounds.max_step_m / r.step_max_m:.1f}×, "
                  f"{bounds.max_turn_deg / r.turn_max_deg:.1f}× and "
                  f"{bounds.max_speed_m_s / r.speed_max_m_s:.1f}× above its largest true step, "
                  "turn and speed")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("sequences", nargs="*",
                        default=[str(SEVEN_SCENES), "synthetic:900", "synthetic-corridor:900"],
                        help="dataset folders or synthetic worlds (default: the bundled "
                             "7-Scenes walk, the synthetic room and corridor)")
    parser.add_argument("--frames", type=int, default=1000, help="frames of each sequence")
    parser.add_argument("--colour-intrinsics", default=str(COLOUR_INTRINSICS),
                        help="a dataset folder's colour camera (its depth registered to it; "
                             "7-Scenes' intrinsics file is its depth camera's); '' for the "
                             "folder's own; not applied to a synthetic world")
    parser.add_argument("--frame-rate", type=float, default=30.0, help="the camera's Hz")
    parser.add_argument("--csv", type=Path, help="write the table's rows here")
    args = parser.parse_args(argv)
    bounds = MotionBounds(speed_window=max(2, round(args.frame_rate / 2)))
    rows: list[MotionFigures] = []
    for sequence in args.sequences:
        colour = args.colour_intrinsics if Path(sequence).is_dir() else None
        rows += measure(sequence, args.frames, colour or None, bounds, args.frame_rate)
    print_table(rows, bounds)
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            out = csv.DictWriter(fh, fieldnames=list(asdict(rows[0])))
            out.writeheader()
            out.writerows(asdict(r) for r in rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
