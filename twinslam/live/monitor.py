"""The monitor node's subscriptions: a live run's protocol topics, poses and map updates into a
:class:`~twinslam.live.run_log.RunLog`, and one status line per slot."""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Mapping
from typing import Any, TypeVar, cast

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image
from twinslam_msgs.msg import (
    FrameSummaries,
    MapStats,
    MapUpdate,
    RateLatent,
    Relocalisation,
    UplinkThroughput,
    UploadRequest,
)

from device_tracker.messages import read_map_update
from msg_schemas import qos, topics
from msg_schemas.headers import stamp_key
from msg_schemas.poses import pose_matrix
from twinslam.live.run_log import RunLog
from twinslam.sequence_player.messages import skipped_frames

M = TypeVar("M")


def received_s(info: Mapping[str, int]) -> float:
    """When a sample reached the monitor's reader (the DDS reception time, system clock, in
    seconds), not when its callback ran: a callback waits while the executor decodes a map,
    and the update loop's stages (:mod:`twinslam.live.update_loop`) would count that wait.
    The callback's time where the middleware gives none."""
    stamp = int(info.get("received_timestamp", 0)) if info else 0
    return stamp * 1e-9 if stamp > 0 else time.time()


class _TakesInfo:
    """A subscription callback that rclpy hands the sample's message info too, on either
    executor: rclpy asks for the info of a callback whose signature takes two parameters, and
    its ``SingleThreadedExecutor`` then calls it with the two, while rclpy 7.1.6's
    ``EventsExecutor`` calls it with one, the (message, info) pair ``take_message`` returned
    (a plain function of two parameters raised ``SystemError: null argument to internal
    routine`` there). This one takes both forms."""

    __signature__ = inspect.Signature([
        inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
        inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])

    def __init__(self, callback: Callable[[Any, Mapping[str, int]], None]) -> None:
        self._callback = callback

    def __call__(self, *taken: Any) -> None:
        msg, info = taken[0] if len(taken) == 1 else taken
        self._callback(msg, info)


def with_info(callback: Callable[[M, Mapping[str, int]], None]) -> Callable[[M], None]:
    """``callback`` as a subscription's that gets the sample's message info too, on the
    ``EventsExecutor`` as on rclpy's Python executors (:class:`_TakesInfo`; rclpy's annotation
    names only the one-parameter form)."""
    return cast(Callable[[M], None], _TakesInfo(callback))


class PipelineMonitor:
    """Subscribes to the run's topics with ``node`` and keeps what it hears."""

    def __init__(self, node: Node,
                 on_stats: Callable[[MapStats, RunLog], None] | None = None,
                 watch_images: bool = False) -> None:
        self.record = RunLog()
        self._on_stats = on_stats
        self._logger = node.get_logger()
        sub = node.create_subscription
        sub(FrameSummaries, topics.FRAME_SUMMARIES, with_info(self._summaries), qos.PROTOCOL)
        #: its publisher count says whether the edge is up (it publishes after warming up)
        self.requests = sub(UploadRequest, topics.UPLOAD_REQUEST, with_info(self._request),
                            qos.PROTOCOL)
        sub(UplinkThroughput, topics.UPLINK_THROUGHPUT, with_info(self._throughput),
            qos.PROTOCOL)
        #: its publisher count says whether the twin is up (it publishes once its model is in)
        self.latents = sub(RateLatent, topics.RATE_LATENT, self._latent, qos.PROTOCOL)
        sub(MapStats, topics.MAP_STATS, self._stats, qos.PROTOCOL)
        # every map the edge sends (not only the latest a late joiner gets)
        map_qos = rclpy.qos.QoSProfile(depth=100, durability=qos.MAP.durability,
                                       reliability=qos.MAP.reliability)
        # taken undecoded, to count their size on the downlink, then decoded once
        sub(MapUpdate, topics.MAP_UPDATE, with_info(self._map), map_qos, raw=True)
        sub(Relocalisation, topics.RELOCALISATION, self._downlink, qos.PROTOCOL, raw=True)
        sub(Path, topics.KEYFRAME_TRAJECTORY, self._trajectory, qos.MAP)
        sub(PoseStamped, topics.DEVICE_POSE, self._pose, qos.PROTOCOL)
        sub(Odometry, topics.DEVICE_ODOM, self._odom, qos.PROTOCOL)
        sub(PoseStamped, topics.GROUND_TRUTH_POSE, self._ground_truth, qos.CAMERA)
        sub(DiagnosticArray, topics.DIAGNOSTICS, self._diagnostics, qos.PROTOCOL)
        if watch_images:     # a viewer's subscription: best effort, undecoded, only counted
            sub(Image, topics.CAMERA_IMAGE, self._image, qos.SENSOR_DATA, raw=True)

    def _summaries(self, msg: FrameSummaries, info: Mapping[str, int]) -> None:
        self.record.hear("summaries", int(msg.slot), received_s(info))
        self.record.summaries[int(msg.slot)] = msg

    def _request(self, msg: UploadRequest, info: Mapping[str, int]) -> None:
        self.record.hear("request", int(msg.slot), received_s(info))
        self.record.requests[int(msg.slot)] = msg

    def _throughput(self, msg: UplinkThroughput, info: Mapping[str, int]) -> None:
        self.record.hear("throughput", int(msg.slot), received_s(info))
        self.record.throughput[int(msg.slot)] = msg

    def _latent(self, msg: RateLatent) -> None:
        self.record.latents[int(msg.slot)] = msg

    def _map(self, data: bytes, info: Mapping[str, int]) -> None:
        heard = received_s(info)
        self._downlink(data)
        try:
            msg = deserialize_message(data, MapUpdate)
        except Exception as exc:     # rclpy's RMW error: a sample cut short (an edge killed
            # while it wrote one) is refused as the nodes' checked subscriptions refuse it,
            # not raised into the executor, which would end the run
            self._logger.error(f"dropped a malformed MapUpdate ({len(data)} bytes): {exc}")
            return
        try:
            snapshot = read_map_update(msg)
        except ValueError as exc:    # well-formed CDR, content no map has (a NaN rotation):
            # refused as the device refuses it, not raised into the executor
            self._logger.error(f"dropped a MapUpdate of slot {int(msg.slot)} it could not "
                               f"read: {exc}")
            return
        self.record.hear("map", int(msg.slot), heard)
        self.record.first_map_versions.setdefault(int(msg.slot), snapshot.version)
        self.record.maps[int(msg.slot)] = snapshot
        self.record.map_stamps[int(msg.slot)] = stamp_key(msg.header)

    def _trajectory(self, msg: Path) -> None:
        stamp = stamp_key(msg.header)
        if stamp >= self.record.trajectory_stamp:
            self.record.trajectory_stamp = stamp
            self.record.keyframe_trajectory = {stamp_key(p.header): pose_matrix(p.pose)
                                               for p in msg.poses}

    def _pose(self, msg: PoseStamped) -> None:
        self.record.poses[stamp_key(msg.header)] = pose_matrix(msg.pose)

    def _odom(self, msg: Odometry) -> None:
        self.record.odom_poses[stamp_key(msg.header)] = pose_matrix(msg.pose.pose)

    def _ground_truth(self, msg: PoseStamped) -> None:
        self.record.ground_truth[stamp_key(msg.header)] = pose_matrix(msg.pose)

    def _downlink(self, data: bytes) -> None:
        self.record.downlink_bytes += len(data)

    def _diagnostics(self, msg: DiagnosticArray) -> None:
        skipped = skipped_frames(msg)
        if skipped is not None:
            self.record.frames_skipped = skipped

    def _image(self, _data: bytes) -> None:
        self.record.images_received += 1

    def _stats(self, msg: MapStats) -> None:
        self.record.stats[int(msg.slot)] = msg
        if self._on_stats:
            self._on_stats(msg, self.record)


def status_line(msg: MapStats, record: RunLog) -> str:
    """One slot as a line: rate, decision, map, uncertainty, timing."""
    slot = int(msg.slot)
    req = record.requests.get(slot)
    summ = record.summaries.get(slot)
    rate = f"{summ.rate_mbps:4.0f}" if summ is not None else "   ?"
    ups = len(req.upload_frame_ids) if req is not None else 0
    ev = len(req.evict_frame_ids) if req is not None else 0
    nu = msg.mean_uncertainty
    return (f"[{msg.policy}] slot {slot:3d} | d_k {rate} Mbit/s | U {ups} C {ev} | map "
            f"{msg.map_size:2d} kf {msg.map_points:6d} pts | u {msg.uncertainty:9.1f} | υ "
            f"{nu:9.1f} lost {msg.lost_share:4.0%} tracked "
            f"{msg.tracked_uncertainty:9.1f} | GTSAM {msg.optimisation_ms:4.0f} ms,"
            f" slot {msg.slot_processing_ms:4.0f} ms")
