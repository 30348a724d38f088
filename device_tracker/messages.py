"""The device's side of the per-slot protocol as messages (DESIGN.md §1 steps 2 and 4): the slot's
``FrameSummaries``, built from plain arrays (the ``Keyframe`` uploads are
:mod:`twinslam.slam.keyframe`'s). Pure conversion, no DDS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from rclpy.serialization import serialize_message
from twinslam_msgs.msg import FrameSummaries, FrameSummary, UplinkThroughput

from device_tracker.uplink_sender import Encoded
from msg_schemas import new
from msg_schemas.headers import ros_time, set_header
from msg_schemas.poses import pose_msg
from twinslam.slam.keyframe import KeyFramePayload, keyframe_message
from twinslam.uplink.shaper import SlotThroughput


@dataclass(frozen=True)
class FrameRecord:
    """One tracked frame of the slot, as the device remembers it until the slot ends."""

    frame_id: int
    stamp: float                   #: capture time, seconds
    pose: np.ndarray               #: 4×4 camera-to-map estimate
    tracked: bool
    map_point_ids: np.ndarray      #: global ids of the last map update it observes
    track_ids: np.ndarray          #: device-local ids of new features it observes
    slot: int                      #: the slot its stamp falls in (:mod:`.slot_clock`)
    relocalised: bool = False      #: tracked again only by relocalisation (after a loss)
    inliers: int = 0               #: matches its pose was solved with (0: not tracked)
    map_version: int = 0           #: the map update it was tracked against (0: none yet)


def frame_summaries_message(slot: int, rate_mbps: float, rate_state: int, map_version: int,
                            frames: list[FrameRecord], stamp: float) -> FrameSummaries:
    msg = new(FrameSummaries, slot=slot, rate_mbps=rate_mbps,
              rate_state=rate_state, map_version=map_version,
              frames=[new(FrameSummary, frame_id=f.frame_id,
                          stamp=ros_time(f.stamp), pose=pose_msg(f.pose), tracked=f.tracked,
                          map_point_ids=np.asarray(f.map_point_ids, dtype=np.uint64),
                          local_track_ids=np.asarray(f.track_ids, dtype=np.uint64),
                          relocalised=f.relocalised, inliers=f.inliers,
                          map_version=f.map_version)
                      for f in frames])
    return set_header(msg, stamp, "map")


def uplink_throughput_message(throughput: SlotThroughput, stamp: float) -> UplinkThroughput:
    """What the uplink carried in a slot, as the edge and the twin read it."""
    t = throughput
    msg = new(UplinkThroughput, slot=t.slot,
              configured_rate_mbps=t.configured_rate_mbps, rate_state=t.rate_state,
              achieved_mbps=t.achieved_mbps, bytes_sent=t.bytes_sent, duration_s=t.duration_s,
              frames_sent=t.frames_sent)
    return set_header(msg, stamp, "")


def encoded_keyframe(data: KeyFramePayload | None, image: object | None, slot: int,
                     alpha_bytes: int) -> Encoded | None:
    """A requested frame as the uplink sends it: (frame id, the serialised ``Keyframe`` of
    ``slot``, the bytes it occupies on the link — at least α); None when the device no longer
    holds the frame (``data`` None)."""
    if data is None:
        return None
    payload = serialize_message(keyframe_message(dataclasses.replace(data, slot=slot),
                                                 image=image))
    return data.frame_id, payload, max(alpha_bytes, len(payload))
