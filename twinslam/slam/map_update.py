"""The edge's map as a map update carries it: what the device tracks against and monitors read.

The edge writes the ``twinslam_msgs/MapUpdate`` from its keyframe map
(:mod:`edge_mapper.messages`); the device reads it into a :class:`MapSnapshot`
(:func:`device_tracker.messages.read_map_update`, which the monitors and benches use too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
    #: the loops' corrections at the walk's head so far, composed (4×4; identity: none): what
    #: a device holds from an update with another one moves by this · that⁻¹
    frame_correction: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: the frame its poses are in (the header's): the device's map frame, or — once the edge
    #: merged the device's map into another device's — that device's
    frame_id: str = ""
