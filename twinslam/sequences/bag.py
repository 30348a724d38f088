"""Recorded rosbag2 (MCAP) files as sequences the player replays like a folder (what
:mod:`twinslam.sequence_player.sequence_bag` writes).

A bag holds exactly what the player publishes — colour, depth, CameraInfo and (when known) the
ground-truth pose on the player's topics, CDR-encoded, stamped with the recorded time — so a run
recorded once replays identically anywhere, without the dataset's own layout. The samples are
serialised by rclpy (the bytes a ROS 2 recorder would store); rosbags writes the MCAP container
with ROS 2 Jazzy's message definitions, so ``ros2 bag play`` reads the bag too.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader

from msg_schemas import message_class, topics
from twinslam.sequences.frame import RgbdFrame, SequenceError, pose_from_xyzq

log = logging.getLogger(__name__)

#: a bag's topics are absolute: the player's topics in the root namespace
TOPICS = {
    "color": (f"/{topics.CAMERA_IMAGE}", "sensor_msgs/msg/Image"),
    "depth": (f"/{topics.CAMERA_DEPTH}", "sensor_msgs/msg/Image"),
    "info": (f"/{topics.CAMERA_INFO}", "sensor_msgs/msg/CameraInfo"),
    "pose": (f"/{topics.GROUND_TRUTH_POSE}", "geometry_msgs/msg/PoseStamped"),
}


@dataclass
class _BagEntry:
    stamp: float


@dataclass
class BagSequence:
    """A recorded bag as a :class:`~twinslam.sequences.frame.Sequence` (streamed, so not
    random access)."""

    path: Path
    kind: str = "rosbag2"
    entries: list[_BagEntry] = field(default_factory=list)
    intrinsics: np.ndarray = field(default_factory=lambda: np.eye(3))
    skipped: list[str] = field(default_factory=list)
    stamps_ns: list[int] = field(default_factory=list)   #: the frames [start, end) to play

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def stamps(self) -> np.ndarray:
        return np.array([e.stamp for e in self.entries])

    def __iter__(self) -> Iterator[RgbdFrame]:
        """Streams the bag: its messages are in time order and a frame's messages share one
        stamp, so a frame is complete when the stamp changes (never the whole bag in memory)."""
        self.skipped = []
        keys = {topic: key for key, (topic, _) in TOPICS.items()}
        wanted = set(self.stamps_ns)
        index = 0
        pending: dict[str, Any] = {}
        pending_t: int | None = None
        with Reader(self.path) as reader:
            conns = [c for c in reader.connections if c.topic in keys]
            for conn, log_ns, raw in reader.messages(connections=conns):
                if log_ns not in wanted:
                    continue
                if pending_t is not None and log_ns != pending_t:
                    frame = self._complete(index, pending_t, pending)
                    if frame is not None:
                        yield frame
                        index += 1
                    pending = {}
                pending_t = log_ns
                pending[keys[conn.topic]] = deserialize_message(raw, message_class(conn.msgtype))
        if pending_t is not None:
            frame = self._complete(index, pending_t, pending)
            if frame is not None:
                yield frame

    def _complete(self, index: int, t: int, msgs: dict[str, Any]) -> RgbdFrame | None:
        if "color" not in msgs or "info" not in msgs:
            self.skipped.append(f"{self.path}@{t}")
            log.warning("skipping the frame stamped %d ns in %s: colour or camera_info missing",
                        t, self.path)
            return None
        return _frame(index, t * 1e-9, msgs)


def _frame(index: int, stamp: float, msgs: dict[str, Any]) -> RgbdFrame:
    c = msgs["color"]
    color = np.frombuffer(bytes(c.data), np.uint8).reshape(c.height, c.width, -1)
    depth = None
    if "depth" in msgs:
        d = msgs["depth"]
        if d.encoding == "16UC1":
            depth = np.frombuffer(bytes(d.data), np.uint16).reshape(d.height, d.width) / 1000.0
        else:
            depth = np.nan_to_num(np.frombuffer(bytes(d.data), np.float32)
                                  .reshape(d.height, d.width))
        depth = depth.astype(np.float32)
    pose = None
    if "pose" in msgs:
        p = msgs["pose"].pose
        pose = pose_from_xyzq([p.position.x, p.position.y, p.position.z, p.orientation.x,
                               p.orientation.y, p.orientation.z, p.orientation.w])
    k = np.asarray(msgs["info"].k, dtype=np.float64).reshape(3, 3)
    return RgbdFrame(index, stamp, color.copy(), depth, k, pose, f"frame@{stamp:.6f}")


def open_bag(path: str | Path, start: int = 0, end: int = -1) -> BagSequence:
    """Index a recorded bag (stamps, intrinsics) without decoding its images."""
    root = Path(path)
    stamps: set[int] = set()
    intrinsics = None
    try:
        with Reader(root) as reader:
            conns = [c for c in reader.connections if c.topic == TOPICS["info"][0]]
            if not conns:
                raise SequenceError(f"{root}: no {TOPICS['info'][0]} in the bag")
            for conn, log_ns, raw in reader.messages(connections=conns):
                stamps.add(log_ns)            # a frame's messages share one bag time
                if intrinsics is None:
                    msg = deserialize_message(raw, message_class(conn.msgtype))
                    intrinsics = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    except SequenceError:
        raise
    except Exception as exc:                    # rosbags raises several error types
        raise SequenceError(f"{root}: not a readable rosbag2 file ({exc})") from None
    ordered = sorted(stamps)
    stop = len(ordered) if end < 0 else min(end, len(ordered))
    chosen = ordered[start:stop]
    if not chosen:
        raise SequenceError(f"{root}: the bag holds no frames in [{start}, {end})")
    if intrinsics is None:
        raise SequenceError(f"{root}: no camera_info in the bag")
    return BagSequence(root, entries=[_BagEntry(t * 1e-9) for t in chosen],
                       intrinsics=intrinsics, stamps_ns=chosen)
