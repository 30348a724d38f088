"""A live run recorded as a rosbag2 (MCAP) that RViz, Foxglove, ``ros2 bag`` and ``rosbags``
open (``twinslam launch --record DIR``).

The monitor's node subscribes to every topic of the run — the protocol, the twin's latents, the
viewer topics, the poses and paths, and the camera — and writes each sample as it arrived on
the wire (CDR, undecoded), stamped with its receive time. The camera's images are kept one in
``camera_every`` (their bytes dominate: ~1 MB a 640×480 colour frame), raw or — ``images:
compressed`` — as ``sensor_msgs/CompressedImage`` on image_transport's ``…/compressed`` topics
(colour JPEG, 16-bit depth lossless PNG, the ``format`` field as image_transport writes it, so
Foxglove and RViz show them). The MCAP chunks are zstd-compressed unless ``chunks: none``
(lossless; every MCAP reader decodes them). The custom interfaces are written with their
definitions (from ``msg_schemas/msg``), so a reader without twinslam decodes them too.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
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
from msg_schemas.interfaces import new, type_name_of

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
    (topics.KEYFRAME_TRAJECTORY, PathMsg, qos.MAP),
    (topics.DEVICE_POSE, PoseStamped, qos.PROTOCOL),
    (topics.DEVICE_PATH, PathMsg, qos.MAP),
    (topics.DEVICE_ODOM, Odometry, qos.PROTOCOL),
    (topics.DIAGNOSTICS, DiagnosticArray, qos.PROTOCOL),
    (topics.GROUND_TRUTH_POSE, PoseStamped, qos.CAMERA),
    (topics.GROUND_TRUTH_PATH, PathMsg, qos.MAP),
    (topics.TF, TFMessage, qos.TF),
    (topics.TF_STATIC, TFMessage, qos.TF_STATIC),
)
#: the camera's topics, kept one sample in ``camera_every``
CAMERA_TOPICS: tuple[tuple[str, type[Any]], ...] = (
    (topics.CAMERA_IMAGE, Image), (topics.CAMERA_DEPTH, Image),
    (topics.CAMERA_INFO, CameraInfo))


#: how the camera's images are kept
IMAGE_MODES = ("raw", "compressed")
#: how the MCAP chunks are stored
CHUNK_MODES = ("zstd", "none")
#: the JPEG quality of a recorded colour image (image_transport's default is 95)
JPEG_QUALITY = 90


@dataclass(frozen=True)
class RecordingOptions:
    """What a recording keeps of the camera and how it stores it."""

    camera_every: int = 10          #: one camera sample (image, depth, camera_info) in this many
    images: str = "raw"             #: one of IMAGE_MODES
    chunks: str = "zstd"            #: one of CHUNK_MODES

    def check(self) -> None:
        """ValueError naming the option a user got wrong."""
        if self.camera_every < 1:
            raise ValueError(f"camera_every must be >= 1, got {self.camera_every}")
        if self.images not in IMAGE_MODES:
            raise ValueError(f"images must be one of {', '.join(IMAGE_MODES)}, got "
                             f"{self.images!r}")
        if self.chunks not in CHUNK_MODES:
            raise ValueError(f"chunks must be one of {', '.join(CHUNK_MODES)}, got "
                             f"{self.chunks!r}")


def compress_image(data: bytes) -> bytes | None:
    """A CDR ``sensor_msgs/Image`` as a CDR ``sensor_msgs/CompressedImage``: colour and mono8
    as JPEG, 16UC1 depth as lossless PNG, with image_transport's ``format`` ("rgb8; jpeg
    compressed bgr8", "16UC1; png compressed"); None for an encoding it does not compress
    (32FC1 depth: the caller keeps it raw)."""
    img = deserialize_message(data, Image)
    h, w, enc = img.height, img.width, img.encoding
    buf = np.frombuffer(bytes(img.data), dtype=np.uint8)
    if enc in ("rgb8", "bgr8"):
        pixels = buf.reshape(h, img.step)[:, :w * 3].reshape(h, w, 3)
        bgr = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR) if enc == "rgb8" else pixels
        ok, out = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        fmt = f"{enc}; jpeg compressed bgr8"
    elif enc == "mono8":
        ok, out = cv2.imencode(".jpg", buf.reshape(h, img.step)[:, :w],
                               [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        fmt = "mono8; jpeg compressed mono8"
    elif enc in ("16UC1", "mono16"):
        dtype = np.dtype(">u2" if img.is_bigendian else "<u2")
        depth = buf.view(dtype).reshape(h, img.step // 2)[:, :w].astype(np.uint16)
        ok, out = cv2.imencode(".png", depth)
        fmt = f"{enc}; png compressed"
    else:
        return None
    if not ok:
        return None
    return bytes(serialize_message(new(CompressedImage, header=img.header, format=fmt,
                                       data=out.reshape(-1))))


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

    def __init__(self, node: Node, folder: Path,
                 options: RecordingOptions = RecordingOptions()) -> None:
        options.check()
        check_destination(folder)
        self.folder, self.options, self.node = folder, options, node
        self._subscriptions: list[Any] = []
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self.store.register(_custom_types())
        self.writer = Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP)
        if options.chunks == "zstd":
            self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()
        self.messages = 0
        self._first_ns: int | None = None
        self._last_ns = 0
        self._seen: dict[str, int] = {}
        for topic, cls, profile in RUN_TOPICS:
            self._subscribe(node, topic, cls, profile, every=1)
        for topic, cls in CAMERA_TOPICS:
            self._subscribe(node, topic, cls, qos.CAMERA, every=options.camera_every,
                            compressed=options.images == "compressed" and cls is Image)

    def _subscribe(self, node: Node, topic: str, cls: type[Any], profile: Any, every: int,
                   compressed: bool = False) -> None:
        name = node.resolve_topic_name(topic)
        # a compressed image goes to image_transport's topic instead of the raw one; an
        # encoding it cannot compress (32FC1 depth) stays raw, on a raw topic made when needed
        packed = self._connection(f"{name}/compressed", CompressedImage, profile) \
            if compressed else None
        raw = None if compressed else self._connection(name, cls, profile)
        self._seen[name] = 0

        def write(data: bytes) -> None:
            nonlocal raw
            self._seen[name] += 1
            if (self._seen[name] - 1) % every:
                return
            now = time.time_ns()
            self._first_ns = now if self._first_ns is None else self._first_ns
            self._last_ns = now
            small = compress_image(data) if packed is not None else None
            if packed is not None and small is not None:
                self.writer.write(packed, now, small)
            else:
                raw = raw or self._connection(name, cls, profile)
                self.writer.write(raw, now, data)
            self.messages += 1

        self._subscriptions.append(node.create_subscription(cls, topic, write, profile,
                                                            raw=True))

    def _connection(self, topic: str, cls: type[Any], profile: Any) -> Connection:
        return self.writer.add_connection(topic, type_name_of(cls), typestore=self.store,
                                          offered_qos_profiles=[bag_qos(profile)])

    def close(self) -> RecordingSummary:
        """Stop listening and finish the bag; what it holds."""
        for sub in self._subscriptions:
            self.node.destroy_subscription(sub)
        self._subscriptions.clear()
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
