"""Reading a ``MapUpdate``: the edge's map as the device and monitors receive it.

The edge writes the message from its keyframe map (``edge_mapper.messages``); everyone who
reads it — the device's tracker, the launcher's monitor, the benches — reads it here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from twinslam_msgs.msg import MapUpdate

from msg_schemas.poses import pose_matrix
from msg_schemas.validation import ORB_DESCRIPTOR_BYTES


@dataclass
class MapSnapshot:
    """The edge's map as one ``MapUpdate`` carried it, as arrays: what the device tracks
    against and what monitors read."""

    version: int
    keyframe_ids: np.ndarray       #: uint64
    keyframe_poses: np.ndarray     #: k×4×4
    point_ids: np.ndarray          #: uint64
    positions: np.ndarray          #: n×3
    descriptors: np.ndarray        #: n×32 uint8
    observations: np.ndarray       #: n uint32
    keyframe_points: list[np.ndarray] = field(default_factory=list)   #: M_f per keyframe
    track_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))
    track_point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))


def read_map_update(msg: MapUpdate) -> MapSnapshot:
    n = len(msg.point_ids)
    return MapSnapshot(int(msg.map_version), np.asarray(msg.keyframe_ids, dtype=np.uint64),
                    np.array([pose_matrix(p) for p in msg.keyframe_poses]).reshape(-1, 4, 4),
                    np.asarray(msg.point_ids, dtype=np.uint64),
                    np.asarray(msg.point_positions, dtype=np.float64).reshape(n, 3),
                    np.asarray(msg.point_descriptors, dtype=np.uint8).reshape(n,
                                                                              ORB_DESCRIPTOR_BYTES),
                    np.asarray(msg.point_observations, dtype=np.uint32),
                    np.split(np.asarray(msg.keyframe_point_ids, dtype=np.uint64),
                             np.cumsum(np.asarray(msg.keyframe_point_counts, dtype=np.int64)
                                       )[:-1]) if len(msg.keyframe_point_counts) else [],
                    np.asarray(msg.track_ids, dtype=np.uint64),
                    np.asarray(msg.track_point_ids, dtype=np.uint64))
