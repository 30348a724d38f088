"""Covisibility datasets from real frames: run the ORB front end over a sequence and keep each
frame's observed map points M_f (and its estimated pose), in the format the simulator reads."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from device_tracker.tracking import Tracking, TrackingConfig
from twinslam.sequence_player.readers import SequenceReader, pose_to_xyzq
from twinslam.simulator.covisibility import CovisibilityDataset


@dataclass
class ExtractionReport:
    frames: int
    skipped: list[str]
    untracked: int          #: frames whose pose was only predicted (too few inliers)
    keyframes: int
    map_points: int
    seconds: float
    frontend_ms: np.ndarray  #: per-frame front-end time (ORB + matching + PnP + bookkeeping)


def extract_covisibility(reader: SequenceReader, config: TrackingConfig | None = None,
                         progress: Callable[[int, int], None] | None = None
                         ) -> tuple[CovisibilityDataset, np.ndarray, ExtractionReport]:
    """(dataset, estimated 4×4 poses, report) for every readable frame of ``reader``.

    ``progress(done, total)`` is called after each frame.
    """
    tracker = Tracking(reader.intrinsics, config)
    sets, stamps, poses, times = [], [], [], []
    untracked = keyframes = 0
    start = time.monotonic()
    total = len(reader)
    for done, frame in enumerate(reader, start=1):
        t0 = time.perf_counter()
        out = tracker.track(frame.color, frame.depth)
        times.append(time.perf_counter() - t0)
        sets.append(out.observed)
        stamps.append(frame.stamp)
        poses.append(out.pose)
        untracked += not out.tracked
        keyframes += out.keyframe
        if progress:
            progress(done, total)
    if not sets:
        raise ValueError(f"{reader.path}: no readable frame")
    source = (f"{reader.kind}:{reader.path.name} ({len(sets)} frames), twinslam ORB front end "
              f"({tracker.config.n_features} features)")
    dataset = CovisibilityDataset.from_sets(
        sets, stamps=np.array(stamps), poses=np.array([pose_to_xyzq(p) for p in poses]),
        source=source)
    report = ExtractionReport(len(sets), list(reader.skipped), untracked, keyframes,
                              len(tracker.map), time.monotonic() - start,
                              np.array(times) * 1000.0)
    return dataset, np.array(poses), report
