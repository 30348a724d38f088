"""A live run recorded as a rosbag2 (MCAP) that RViz, Foxglove, ``ros2 bag`` and ``rosbags``
open (``twinslam launch --record DIR``, issue #31).

The monitor's node subscribes to every topic of the run — the protocol, the twin's latents, the
viewer topics, the poses and paths, and the camera — and writes each sample as it arrived on
the wire (CDR, undecoded), stamped with its receive time. The camera's images are kept one in
``camera_every`` (their bytes dominate: ~1 MB a 640×480 colour frame). The custom interfaces
are written with their definitions (from ``msg_schemas/msg``), so a reader without twinslam
decodes them too.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geometry_msgs.msg import PoseArray, PoseStamped
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from tf2_msgs.msg import TFMessage
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    MapUpdate,
    RateLatent,
    UplinkThroughput,
    UploadRequest,
)
from visualization_msgs.msg import MarkerArray

import msg_schemas
from msg_schemas import qos, topics
from msg_schemas.interfaces import type_name_of

#: a recording refuses to start with less free space than this where it writes
MIN_FREE_BYTES = 200 * 1024 * 1024
#: every topic of a run but the camera's: (topic, message class, QoS)
RUN_TOPICS: tuple[tuple[str, type[Any], Any], ...] = (
    (topics.FRAME_SUMMARIES, FrameSummaries, qos.PROTOCOL),
    (topics.KEYFRAMES, Keyframe, qos.PROTOCOL),
    (topics.UPLOAD_REQUEST, UploadRequest, qos.PROTOCOL),
    (topics.UPLINK_THROUGHPUT, UplinkThroughput, qos.PROTOCOL),
    (topics.MAP_STATS, MapStats, qos.PROTOCOL),
    (topics.MAP_UPDATE, MapUpdate, qos.MAP),
    (topics.RATE_LATENT, RateLatent, qos.PROTOCOL),
    (topics.MAP_POINTS, PointCloud2, qos.MAP),
    (topics.KEYFRAME_POSES, PoseArray, qos.MAP),
    (topics.DECISIONS, MarkerArray, qos.MAP),
    (topics.DEVICE_POSE, PoseStamped, qos.PROTOCOL),
    (topics.DEVICE_PATH, PathMsg, qos.MAP),
    (topics.GROUND_TRUTH_POSE, PoseStamped, qos.CAMERA),
    (topics.GROUND_TRUTH_PATH, PathMsg, qos.MAP),
    (topics.TF, TFMessage, qos.TF),
    (topics.TF_STATIC, TFMessage, qos.TF_STATIC),
)
#: the camera's topics, kept one sample in ``camera_every``
CAMERA_TOPICS: tuple[tuple[str, type[Any]], ...] = (
    (topics.CAMERA_IMAGE, Image), (topics.CAMERA_DEPTH, Image),
    (topics.CAMERA_INFO, CameraInfo))


def check_destination(folder: Path) -> None:
    """ValueError naming why ``folder`` cannot take a recording: it exists already (rosbag2
    writes a new folder), its parent is missing or not writable, or the disk is nearly full.
    Called before a run starts, so nothing is played for a recording that cannot be written."""
    if folder.exists():
        raise ValueError(f"{folder} exists; a recording goes to a new folder")
    parent = folder.parent
    if not parent.is_dir():
        raise ValueError(f"{parent} does not exist")
    probe = parent / f".twinslam-write-test-{time.monotonic_ns()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"{parent} is not writable ({exc.strerror})") from None
    free = shutil.disk_usage(parent).free
    if free < MIN_FREE_BYTES:
        raise ValueError(f"{parent}: only {free / 2**20:.0f} MiB free, a recording needs at "
                         f"least {MIN_FREE_BYTES / 2**20:.0f} MiB")


@dataclass
class RecordingSummary:
    path: Path
    messages: int
    bytes: int                      #: on disk, after the bag was closed
    seconds: float                  #: from the first to the last message

    @property
    def mb_per_minute(self) -> float:
        return self.bytes / 1e6 / (self.seconds / 60) if self.seconds > 0 else 0.0


class RunRecorder:
    """Subscribes with ``node`` and writes what it hears to the MCAP bag ``folder``."""

    def __init__(self, node: Node, folder: Path, camera_every: int = 10) -> None:
        if camera_every < 1:
            raise ValueError(f"camera_every must be >= 1, got {camera_every}")
        check_destination(folder)
        self.folder, self.camera_every = folder, camera_every
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self.store.register(_custom_types())
        self.writer = Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.messages = 0
        self._first_ns: int | None = None
        self._last_ns = 0
        self._seen: dict[str, int] = {}
        for topic, cls, profile in RUN_TOPICS:
            self._subscribe(node, topic, cls, profile, every=1)
        for topic, cls in CAMERA_TOPICS:
            self._subscribe(node, topic, cls, qos.CAMERA, every=camera_every)

    def _subscribe(self, node: Node, topic: str, cls: type[Any], profile: Any, every: int
                   ) -> None:
        name = node.resolve_topic_name(topic)
        conn = self.writer.add_connection(name, type_name_of(cls), typestore=self.store,
                                          offered_qos_profiles=[bag_qos(profile)])
        self._seen[name] = 0

        def write(data: bytes) -> None:
            self._seen[name] += 1
            if (self._seen[name] - 1) % every:
                return
            now = time.time_ns()
            self._first_ns = now if self._first_ns is None else self._first_ns
            self._last_ns = now
            self.writer.write(conn, now, data)
            self.messages += 1

        node.create_subscription(cls, topic, write, profile, raw=True)

    def close(self) -> RecordingSummary:
        """Finish the bag; what it holds."""
        self.writer.close()
        size = sum(f.stat().st_size for f in self.folder.rglob("*") if f.is_file())
        span = (self._last_ns - (self._first_ns or self._last_ns)) * 1e-9
        return RecordingSummary(self.folder, self.messages, size, span)


def bag_qos(profile: QoSProfile) -> Qos:
    """The QoS a topic was offered with, as the bag's metadata keeps it: ``ros2 bag play``
    offers it again, so the latched topics (the map, ``/tf_static``) reach a late viewer."""
    never = QosTime(0, 0)                 # rosbag2's "default": no deadline, lifespan, lease
    return Qos(QosHistory(profile.history.value), profile.depth,
               QosReliability(profile.reliability.value), QosDurability(profile.durability.value),
               never, never, QosLiveliness.AUTOMATIC, never, False)


def _custom_types() -> dict[str, Any]:
    """twinslam_msgs' definitions as rosbags reads them, from the one source of truth."""
    folder = Path(msg_schemas.__file__).resolve().parent / "msg"    # shipped as package data
    types: dict[str, Any] = {}
    for path in sorted(folder.glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"),
                                        f"twinslam_msgs/msg/{path.stem}"))
    return types
