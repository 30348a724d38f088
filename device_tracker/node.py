"""device_tracker: the device's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``camera/image_raw`` + ``camera/depth/image_raw`` + ``camera/camera_info`` → every frame
  tracked against the local map (:class:`~device_tracker.device_core.DeviceTrackerCore`);
  ``device/pose`` (``PoseStamped``) per frame, ``device/path`` (``nav_msgs/Path``) per slot;
* at each slot's end, ``device/frame_summaries`` with d_k, drawn from the configured channel
  model (``channel:=markov:N=2`` or ``trace:FILE``, as the simulator's);
* ``edge/upload_request`` → exactly the frames asked for go out as ``Keyframe`` messages on
  ``device/keyframes`` through the :class:`~device_tracker.uplink_shaper.UplinkShaper`, on an
  upload thread so tracking never waits for the uplink; each frame occupies the link for
  ``alpha_mbit`` (the paper's compressed frame, 5 Mbit) or its real size if larger; then the
  slot's ``device/uplink_throughput``;
* ``edge/map_update`` (transient local) → the new local map.

Topic names are relative, so ``-r __ns:=/ar1`` moves the device with its edge and camera.

``shaper:=tc`` hands the pacing to the kernel instead (:mod:`device_tracker.tc_shaper`): a
``tbf`` of rate d_k on ``uplink_interface`` each slot, optional ``netem_delay_ms`` /
``netem_loss_percent``, and the slot's throughput measured on the interface. With
``upload_image:=true`` a keyframe also carries its colour image, so the bytes on the link are a
real frame's.

The edge can become unreachable (a link down, an edge restarting): when a slot's summaries get
no ``UploadRequest`` within ``edge_timeout_s``, the device says it goes on tracking on its local
map, and says so again when the edge answers; uploads then resume from the slots it asks for.

A frame the motion model loses is relocalised against the whole local map; the node logs when
tracking is lost and when it comes back. A colour image without its depth within a few frames
is tracked without depth (no new points from it).
"""

from __future__ import annotations

import queue
import sys
import threading
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapUpdate,
    UplinkThroughput,
    UploadRequest,
)

from device_tracker.camera_input import depth_array, image_array
from device_tracker.device_core import DeviceTrackerCore
from device_tracker.messages import frame_summaries_message, keyframe_message
from device_tracker.tc_shaper import NetemConfig, TcShaper
from device_tracker.tracking import TrackingConfig
from device_tracker.uplink_shaper import ShaperError, UplinkShaper
from edge_mapper.messages import read_map_update
from msg_schemas import new, qos, topics
from msg_schemas.headers import set_header, stamp_key, stamp_seconds
from msg_schemas.poses import pose_msg
from node_hosts.acks import wait_for_acks
from node_hosts.checked_subscription import CheckedSubscription
from node_hosts.node_main import NodeStartError, run_node
from node_hosts.parameters import ParamSpec, declare
from udt_node.channel import ChannelError, parse_channel

SHAPERS = ("token_bucket", "tc")
PARAMETERS = (
    ParamSpec("slot_frames", 60, "F, frames per slot", low=1, high=100_000),
    ParamSpec("alpha_mbit", 5.0, "alpha, uplink Mbit one uploaded frame occupies (at least)",
              low=1e-6, high=1e6),
    ParamSpec("channel", "markov:N=2", "uplink rate model: markov:N=2[,K=...] or "
              "trace:FILE[,N=4] (CSV time_s,throughput_mbps)"),
    ParamSpec("rate_min", 40.0, "Mbit/s the channel's lowest state", low=0.0, high=1e6),
    ParamSpec("rate_max", 80.0, "Mbit/s the channel's highest state", low=0.0, high=1e6),
    ParamSpec("seed", 0, "seed of the channel model", low=0),
    ParamSpec("n_features", 1000, "ORB features per frame", low=10, high=100_000),
    ParamSpec("map_frame", "map", "frame id of the device's poses and path"),
    ParamSpec("shaper", "token_bucket", "uplink shaper: token_bucket (in process) or tc (a "
              "tbf of rate d_k on uplink_interface; CAP_NET_ADMIN)",
              check=lambda v: None if v in SHAPERS else f"must be one of {', '.join(SHAPERS)}"),
    ParamSpec("uplink_interface", "eth0", "interface tc shapes (shaper:=tc)"),
    ParamSpec("netem_delay_ms", 0.0, "tc netem delay on the uplink (kernels with sch_netem)",
              low=0.0, high=60_000.0),
    ParamSpec("netem_loss_percent", 0.0, "tc netem random loss on the uplink", low=0.0,
              high=100.0),
    ParamSpec("upload_image", False, "keyframes carry their colour image too (real frame "
              "bytes on the link)"),
    ParamSpec("edge_timeout_s", 3.0, "no upload request for this long: say the edge is silent",
              low=0.01, high=3600.0),
    ParamSpec("keep_slots", 4, "slots whose frames stay uploadable (rides out ~5 s outages)",
              low=1, high=1000),
)
#: how long one keyframe write may keep failing (the writer's history full of unacknowledged
#: keyframes while the link is down) before that keyframe is given up
WRITE_RETRY_S = 30.0
MAX_PENDING = 5                     #: colour frames waiting for their depth at most


class DeviceTrackerNode(Node):
    def __init__(self) -> None:
        super().__init__("device_tracker")
        p = declare(self, PARAMETERS)
        self.slot_frames = int(p["slot_frames"])
        self.alpha_bytes = int(float(p["alpha_mbit"]) * 1e6 / 8)
        self.channel_spec = str(p["channel"])
        try:
            self.channel = parse_channel(self.channel_spec,
                                         (float(p["rate_min"]), float(p["rate_max"])),
                                         int(p["seed"]))
        except (ChannelError, ValueError) as exc:
            raise NodeStartError(str(exc)) from None
        self.map_frame = str(p["map_frame"])
        self.tracking_config = TrackingConfig(n_features=int(p["n_features"]), relocalise=True)
        self.core: DeviceTrackerCore | None = None
        # the publisher the tc shaper flushes exists before the shaper
        self.pub_keyframes = self.create_publisher(Keyframe, topics.KEYFRAMES, qos.PROTOCOL)
        try:
            self.shaper = self._make_shaper(p)
        except (ShaperError, ValueError) as exc:
            raise NodeStartError(str(exc)) from None
        self.upload_image = bool(p["upload_image"])
        #: slots whose frames stay uploadable: 4 ride out a link down for ~5 s
        self.keep_slots = int(p["keep_slots"])
        self.images: dict[int, Any] = {}                  # frame id → colour image, if uploaded
        self.edge_timeout = float(p["edge_timeout_s"])
        self._unanswered: dict[int, float] = {}           # slot → when its summaries went out
        self._edge_silent_since: float | None = None
        self.slot_rates: dict[int, tuple[float, int]] = {}
        self.pending: dict[int, dict[str, Any]] = {}      # stamp → colour / depth messages
        self._latest = {"color": -1, "depth": -1}         # newest stamp seen per topic
        self.skipped = 0
        self.path: list[Any] = []
        self._uploads: queue.Queue[tuple[int, list[int]] | None] = queue.Queue()
        DeviceTrackerCore.warm_up()
        self._lock = threading.Lock()                     # the core, between the threads

        self.pub_pose = self.create_publisher(PoseStamped, topics.DEVICE_POSE, qos.PROTOCOL)
        self.pub_path = self.create_publisher(Path, topics.DEVICE_PATH, qos.MAP)
        self.pub_summaries = self.create_publisher(FrameSummaries, topics.FRAME_SUMMARIES,
                                                   qos.PROTOCOL)
        self.pub_throughput = self.create_publisher(UplinkThroughput, topics.UPLINK_THROUGHPUT,
                                                    qos.PROTOCOL)
        self.sub_color = CheckedSubscription(self, Image, topics.CAMERA_IMAGE,
                                             lambda m: self._on_image("color", m), qos.CAMERA)
        self.sub_depth = CheckedSubscription(self, Image, topics.CAMERA_DEPTH,
                                             lambda m: self._on_image("depth", m), qos.CAMERA)
        self.sub_info = CheckedSubscription(self, CameraInfo, topics.CAMERA_INFO,
                                            self._on_camera_info, qos.CAMERA)
        self.sub_request = CheckedSubscription(self, UploadRequest, topics.UPLOAD_REQUEST,
                                               self._on_upload_request, qos.PROTOCOL)
        self.sub_map = CheckedSubscription(self, MapUpdate, topics.MAP_UPDATE,
                                           self._on_map_update, qos.MAP)
        self.create_timer(0.5, self._check_edge)
        self._uploader = threading.Thread(target=self._upload_loop, name="uplink", daemon=True)
        self._uploader.start()

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _make_shaper(self, p: dict[str, Any]) -> UplinkShaper | TcShaper:
        kind = str(p["shaper"])
        if kind == "token_bucket":
            return UplinkShaper()
        if kind != "tc":
            raise ValueError(f"shaper must be one of {', '.join(SHAPERS)}, got {kind!r}")
        netem = NetemConfig(float(p["netem_delay_ms"]), float(p["netem_loss_percent"]))
        shaper = TcShaper(str(p["uplink_interface"]), netem,
                          flush=lambda: wait_for_acks(self.pub_keyframes, WRITE_RETRY_S))
        shaper.start(float(self.channel.rates[0]))
        return shaper

    # -- camera ------------------------------------------------------------------------------

    def _on_camera_info(self, msg: Any) -> None:
        if self.core is None:
            k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
            self.core = DeviceTrackerCore(k, self.slot_frames, self.tracking_config,
                                          self.keep_slots)
            self.get_logger().info(f"camera {msg.width}x{msg.height}, fx {k[0, 0]:.1f}; "
                                        "tracking starts")
        self._process_ready()

    def _on_image(self, kind: str, msg: Any) -> None:
        key = stamp_key(msg.header)
        self.pending.setdefault(key, {})[kind] = msg
        self._latest[kind] = max(self._latest[kind], key)
        self._process_ready()

    def _process_ready(self) -> None:
        """Track complete frames oldest first. Each topic delivers in stamp order, so a frame
        still missing its depth once a newer depth came will never get it: its colour is
        tracked without depth (and a lone depth image dropped). With no depth topic at all,
        colour waits at most ``MAX_PENDING`` frames. (Counting pending frames alone is wrong
        under load: the executor may take ten colour images before their depth images.)"""
        if self.core is None:
            return
        while self.pending:
            oldest = min(self.pending)
            entry = self.pending[oldest]
            complete = "color" in entry and "depth" in entry
            missing = "depth" if "color" in entry else "color"
            hopeless = self._latest[missing] > oldest or (
                self._latest["depth"] < 0 and len(self.pending) > MAX_PENDING)
            if not complete and not hopeless:
                return
            del self.pending[oldest]
            if "color" not in entry:
                self.skipped += 1
                self.get_logger().warning(
                    f"depth image of stamp {oldest / 1e9:.3f} s without its colour image "
                    f"(newest colour {self._latest['color'] / 1e9:.3f} s): skipped")
                continue
            self._track(entry["color"], entry.get("depth"))

    def _track(self, color_msg: Any, depth_msg: Any | None) -> None:
        assert self.core is not None
        try:
            color = image_array(color_msg)
            depth = depth_array(depth_msg) if depth_msg is not None else None
        except ValueError as exc:
            self.skipped += 1
            self.get_logger().error(f"frame skipped: {exc}")
            return
        stamp = stamp_seconds(color_msg.header)
        with self._lock:
            was_lost = self.core.lost
            result = self.core.track(color, depth, stamp)
        record = result.record
        log = self.get_logger()
        if not record.tracked and not was_lost:
            log.warning(f"frame {record.frame_id}: tracking lost; relocalising against the "
                        "local map")
        elif result.relocalised or (was_lost and record.tracked):
            log.info(f"frame {record.frame_id}: relocalised")
        if self.upload_image:
            self.images[record.frame_id] = color_msg
            horizon = record.frame_id - (self.keep_slots + 1) * self.slot_frames
            for old in [f for f in self.images if f < horizon]:
                del self.images[old]
        pose = set_header(PoseStamped(pose=pose_msg(record.pose)), stamp, self.map_frame)
        self.pub_pose.publish(pose)
        self.path.append(pose)
        if result.slot_done:
            self._end_slot(stamp)

    def _end_slot(self, stamp: float) -> None:
        assert self.core is not None
        with self._lock:
            frames = self.core.take_slot()
            version = self.core.map_version
        slot = self.core.slot_of(frames[-1].frame_id)
        state, rate = self.channel.step()
        self.slot_rates[slot] = (rate, state)
        self._unanswered[slot] = time.monotonic()
        self.pub_summaries.publish(frame_summaries_message(slot, rate, state, version, frames,
                                                           stamp))
        path = Path(poses=list(self.path))
        self.pub_path.publish(set_header(path, stamp, self.map_frame))
        tracked = sum(f.tracked for f in frames)
        self.get_logger().info(
            f"slot {slot}: {len(frames)} frames ({tracked} tracked, {self.skipped} skipped so "
            f"far; {self.sub_color.received} colour / {self.sub_depth.received} depth images "
            f"received), d_k {rate:.1f} Mbit/s, map version {version}, "
            f"{len(self.core.tracking.map)} local points")

    # -- edge --------------------------------------------------------------------------------

    def _on_map_update(self, msg: Any) -> None:
        if self.core is None:
            return
        update = read_map_update(msg)
        with self._lock:
            applied = self.core.apply_map_update(update, int(msg.slot))
        if applied:
            self.get_logger().debug(f"map version {update.version}: "
                                         f"{len(update.point_ids)} points")

    def _on_upload_request(self, msg: Any) -> None:
        slot = int(msg.slot)
        for answered in [k for k in self._unanswered if k <= slot]:
            del self._unanswered[answered]     # older ones the edge will not answer now
        if self._edge_silent_since is not None:
            self.get_logger().info(
                f"slot {slot}: the edge answers again after "
                f"{time.monotonic() - self._edge_silent_since:.1f} s of silence; uploads resume")
            self._edge_silent_since = None
        self._uploads.put((slot, [int(f) for f in msg.upload_frame_ids]))

    def _check_edge(self) -> None:
        """Say once when the edge stops answering: the device keeps tracking regardless."""
        if self._edge_silent_since is not None or not self._unanswered:
            return
        slot = min(self._unanswered)
        waited = time.monotonic() - self._unanswered[slot]
        if waited > self.edge_timeout:
            self._edge_silent_since = self._unanswered[slot]
            points = len(self.core.tracking.map) if self.core else 0
            version = self.core.map_version if self.core else 0
            self.get_logger().warning(
                f"slot {slot}: no upload request from the edge for {waited:.1f} s (link down "
                f"or edge gone?); tracking on the local map (version {version}, {points} "
                "points) until it answers")

    def _encode_keyframe(self, slot: int, frame_id: int) -> tuple[int, bytes, int] | None:
        """(frame id, CDR bytes, bytes the uplink is charged) of a requested frame; None, and
        an error logged, when the device no longer holds it."""
        with self._lock:
            data = self.core.upload(frame_id) if self.core else None
        if data is None:
            self.get_logger().error(f"slot {slot}: frame {frame_id} was asked for but is "
                                         "no longer held; not sent")
            return None
        msg = keyframe_message(slot, data.frame_id, data.stamp, data.pose,
                               self.core.k if self.core else np.eye(3), data.keypoints,
                               data.depths, data.descriptors, data.point_ids,
                               image=self.images.get(frame_id))
        payload = serialize_message(msg)
        return frame_id, payload, max(self.alpha_bytes, len(payload))

    def _publish_keyframe(self, slot: int, frame_id: int, payload: bytes) -> None:
        """Write one keyframe, retrying while the writer is blocked (a reliable writer whose
        readers stopped acknowledging times out after its max blocking time)."""
        deadline = time.monotonic() + WRITE_RETRY_S
        while True:
            try:
                self.pub_keyframes.publish(payload)
                return
            except Exception as exc:           # rclpy's RCLError: the write timed out
                if time.monotonic() > deadline:
                    self.get_logger().error(
                        f"slot {slot}: keyframe {frame_id} not written within "
                        f"{WRITE_RETRY_S:g} s ({exc}); given up")
                    return
                time.sleep(0.1)

    def _upload_loop(self) -> None:
        """Sends each slot's requested frames through the shaper, then its throughput."""
        while (job := self._uploads.get()) is not None:
            slot, frame_ids = job
            rate, state = self.slot_rates.get(slot, (self.channel.rates[0], 0))
            # encoded before the slot's transfer starts, so the link never waits for the CPU
            payloads = [p for f in frame_ids if (p := self._encode_keyframe(slot, f))]
            self.shaper.start_slot(slot, rate, state)
            for frame_id, payload, size in payloads:
                self.shaper.send(size, lambda b=payload, f=frame_id, k=slot:
                                 self._publish_keyframe(k, f, b))
            t = self.shaper.end_slot()
            out = new("twinslam_msgs/msg/UplinkThroughput", slot=t.slot,
                      configured_rate_mbps=t.configured_rate_mbps, rate_state=t.rate_state,
                      achieved_mbps=t.achieved_mbps, bytes_sent=t.bytes_sent,
                      duration_s=t.duration_s, frames_sent=t.frames_sent)
            self.pub_throughput.publish(set_header(out, self._now(), ""))

    def close(self) -> None:
        self._uploads.put(None)
        self._uploader.join(timeout=5.0)
        if isinstance(self.shaper, TcShaper):
            self.shaper.close()


def main(args: list[str] | None = None) -> int:
    def started(device: DeviceTrackerNode) -> None:
        shaper = (f"tc on {device.shaper.interface}" if isinstance(device.shaper, TcShaper)
                  else "token bucket")
        device.get_logger().info(
            f"slots of {device.slot_frames} frames, channel {device.channel_spec}, uplink "
            f"shaper {shaper}; waiting for {device.resolve_topic_name(topics.CAMERA_INFO)}")

    return run_node("device_tracker", DeviceTrackerNode, args, started=started)


if __name__ == "__main__":
    sys.exit(main())
