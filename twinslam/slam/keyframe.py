"""A keyframe as the uplink carries it: one payload type for the device that sends it and the
edge that integrates it. The messages it travels in are the nodes' business: the device
writes a ``twinslam_msgs/Keyframe`` of it (:func:`device_tracker.messages.keyframe_message`),
the edge reads one back (:func:`edge_mapper.messages.read_keyframe`).

The device fills it from a tracked frame (features, their depths, the id each feature
observes), the edge reads it back to associate and create map points. Feature ids share one
64-bit space: a map point's global id, or a device-local track id with :data:`TRACK_ID_BIT`
set, or 0 for a feature associated with nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TRACK_ID_BIT = np.uint64(1 << 63)          #: marks a device-local track id


def is_track(ids: np.ndarray) -> np.ndarray:
    """The mask of ``ids`` (uint64) that are device-local track ids, not map points."""
    return np.asarray((np.asarray(ids, dtype=np.uint64) & TRACK_ID_BIT) != 0)


def is_track_id(point_id: int | np.integer) -> bool:
    """Whether one id is a device-local track id."""
    return bool(int(point_id) & int(TRACK_ID_BIT))


def as_track_ids(ids: np.ndarray) -> np.ndarray:
    """Device-local counters as track ids (the bit set)."""
    return np.asarray(np.asarray(ids, dtype=np.uint64) | TRACK_ID_BIT)


def track_counters(ids: np.ndarray) -> np.ndarray:
    """Track ids as the device-local counters they mark (the bit cleared, int64):
    :func:`as_track_ids` undone."""
    return np.asarray((np.asarray(ids, dtype=np.uint64) & ~TRACK_ID_BIT).astype(np.int64))


@dataclass(frozen=True)
class KeyFramePayload:
    """What a ``Keyframe`` message carries for one frame, as arrays."""

    frame_id: int
    slot: int
    stamp: float                   #: capture time, seconds
    pose: np.ndarray               #: 4×4 camera-to-map (the device's estimate)
    intrinsics: np.ndarray         #: 3×3
    keypoints: np.ndarray          #: n×2 float32
    depths: np.ndarray             #: n float32, metres, 0 = none
    descriptors: np.ndarray        #: n×32 uint8
    point_ids: np.ndarray          #: n uint64: global id, TRACK_ID_BIT | track id, or 0
