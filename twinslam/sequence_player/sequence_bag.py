"""``twinslam record``: a sequence written as a rosbag2 (MCAP) of exactly what the player
publishes for each frame, which :mod:`twinslam.sequences.bag` reads back as a sequence.

The samples are serialised by rclpy (the bytes a ROS 2 recorder would store); rosbags writes
the container with ROS 2 Jazzy's message definitions, so ``ros2 bag play`` reads it too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from twinslam.sequence_player.messages import (
    camera_info_message,
    color_message,
    depth_message,
    pose_message,
)
from twinslam.sequences.bag import TOPICS
from twinslam.sequences.frame import RgbdFrame, Sequence, SequenceError


def frame_messages(frame: RgbdFrame, stamp: float, frame_id: str = "camera",
                   world_frame_id: str = "world", depth_encoding: str = "16UC1"
                   ) -> dict[str, Any]:
    """The messages the player publishes for one frame, by TOPICS key."""
    msgs = {"color": color_message(frame, stamp, frame_id),
            "info": camera_info_message(frame, stamp, frame_id)}
    if frame.depth is not None:
        msgs["depth"] = depth_message(frame, stamp, frame_id, depth_encoding)
    if frame.pose is not None:
        msgs["pose"] = pose_message(frame.pose, stamp, world_frame_id)
    return msgs


def record_bag(reader: Sequence, path: str | Path) -> int:
    """Write ``reader``'s frames to a new rosbag2 MCAP folder ``path``; returns the frames
    written (corrupt ones are skipped as in playback)."""
    out = Path(path)
    if out.exists():
        raise SequenceError(f"{out} exists; rosbag2 writes a new folder")
    store = get_typestore(Stores.ROS2_JAZZY)     # the message definitions the bag records
    written = 0
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {key: writer.add_connection(topic, kind, typestore=store)
                 for key, (topic, kind) in TOPICS.items()}
        for frame in reader:
            ns = round(frame.stamp * 1e9)
            for key, msg in frame_messages(frame, frame.stamp).items():
                writer.write(conns[key], ns, serialize_message(msg))
            written += 1
    return written
