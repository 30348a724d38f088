"""device_tracker: the device's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``/camera/image_raw`` + ``/camera/depth/image_raw`` + ``/camera/camera_info`` → every frame
  tracked against the local map (:class:`~device_tracker.device_core.DeviceTrackerCore`);
  ``/device/pose`` (``PoseStamped``) per frame, ``/device/path`` (``nav_msgs/Path``) per slot;
* at each slot's end, ``/device/frame_summaries`` with d_k, drawn from the configured channel
  model (``channel:=markov:N=2`` or ``trace:FILE``, as the simulator's);
* ``/edge/upload_request`` → exactly the frames asked for go out as ``Keyframe`` messages on
  ``/device/keyframes`` through the :class:`~device_tracker.uplink_shaper.UplinkShaper`, on an
  upload thread so tracking never waits for the uplink; each frame occupies the link for
  ``alpha_mbit`` (the paper's compressed frame, 5 Mbit) or its real size if larger; then the
  slot's ``/device/uplink_throughput``;
* ``/edge/map_update`` (latched) → the new local map.

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

import node_runtime
from device_tracker.camera_input import depth_array, image_array, stamp_key, stamp_seconds
from device_tracker.device_core import DeviceTrackerCore
from device_tracker.messages import frame_summaries_message, keyframe_message
from device_tracker.tc_shaper import NetemConfig, TcShaper
from device_tracker.tracking import TrackingConfig
from device_tracker.uplink_shaper import ShaperError, UplinkShaper
from edge_mapper.messages import read_map_update
from msg_schemas import new
from msg_schemas.poses import pose_msg
from node_runtime import PROTOCOL
from sequence_player.messages import set_header
from udt_node.channel import ChannelError, parse_channel

PARAMETERS = {"slot_frames": 60, "alpha_mbit": 5.0, "channel": "markov:N=2",
              "rate_min": 40.0, "rate_max": 80.0, "seed": 0, "n_features": 1000,
              "map_frame": "map", "shaper": "token_bucket", "uplink_interface": "eth0",
              "netem_delay_ms": 0.0, "netem_loss_percent": 0.0, "upload_image": False,
              "edge_timeout_s": 3.0, "keep_slots": 4}
SHAPERS = ("token_bucket", "tc")
#: how long one keyframe write may keep failing (the writer's history full of unacknowledged
#: keyframes while the link is down) before that keyframe is given up
WRITE_RETRY_S = 30.0
#: camera topics: reliable and 5 s deep. A reader keeps the last `depth` samples not yet
#: taken; a device that falls behind by more loses frames and its slot clock with them (a
#: clean checkout's device lagged 2.5 s over its first frames on a 2-core host and lost a
#: colour image at depth 60). Memory is only held while behind: ~1.5 MB a frame.
CAMERA_QOS = node_runtime.QoSProfile(depth=150)
MAX_PENDING = 5                     #: colour frames waiting for their depth at most


class DeviceTrackerNode:
    def __init__(self, node: node_runtime.Node) -> None:
        self.node = node
        p = {k: node.get_parameter(k).value for k in PARAMETERS}
        self.slot_frames = int(p["slot_frames"])
        if self.slot_frames < 1:
            raise ValueError(f"slot_frames must be >= 1, got {self.slot_frames}")
        if not float(p["alpha_mbit"]) > 0:
            raise ValueError(f"alpha_mbit must be > 0, got {p['alpha_mbit']}")
        self.alpha_bytes = int(float(p["alpha_mbit"]) * 1e6 / 8)
        self.channel = parse_channel(str(p["channel"]),
                                     (float(p["rate_min"]), float(p["rate_max"])),
                                     int(p["seed"]))
        self.map_frame = str(p["map_frame"])
        self.tracking_config = TrackingConfig(n_features=int(p["n_features"]), relocalise=True)
        self.core: DeviceTrackerCore | None = None
        self.shaper = self._make_shaper(p)
        self.upload_image = bool(p["upload_image"])
        #: slots whose frames stay uploadable: 4 ride out a link down for ~5 s
        self.keep_slots = int(p["keep_slots"])
        if self.keep_slots < 1:
            raise ValueError(f"keep_slots must be >= 1, got {self.keep_slots}")
        self.images: dict[int, Any] = {}                  # frame id → colour image, if uploaded
        self.edge_timeout = float(p["edge_timeout_s"])
        if not self.edge_timeout > 0:
            raise ValueError(f"edge_timeout_s must be > 0, got {self.edge_timeout}")
        self._unanswered: dict[int, float] = {}           # slot → when its summaries went out
        self._edge_silent_since: float | None = None
        self.slot_rates: dict[int, tuple[float, int]] = {}
        self.pending: dict[int, dict[str, Any]] = {}      # stamp → colour / depth messages
        self._latest = {"color": -1, "depth": -1}         # newest stamp seen per topic
        self.skipped = 0
        self.path: list[Any] = []
        self._uploads: queue.Queue[tuple[int, list[int]] | None] = queue.Queue()
        DeviceTrackerCore.warm_up(np.array([[525.0, 0, 320], [0, 525, 240], [0, 0, 1]]))
        self._lock = threading.Lock()                     # the core, between the threads

        self.pub_pose = node.create_publisher("geometry_msgs/msg/PoseStamped", "/device/pose",
                                              node_runtime.DEFAULT)
        self.pub_path = node.create_publisher("nav_msgs/msg/Path", "/device/path",
                                              node_runtime.LATCHED)
        self.pub_summaries = node.create_publisher("twinslam_msgs/msg/FrameSummaries",
                                                   "/device/frame_summaries", PROTOCOL)
        self.pub_keyframes = node.create_publisher("twinslam_msgs/msg/Keyframe",
                                                   "/device/keyframes", PROTOCOL)
        self.pub_throughput = node.create_publisher("twinslam_msgs/msg/UplinkThroughput",
                                                    "/device/uplink_throughput", PROTOCOL)
        self.sub_color = node.create_subscription(
            "sensor_msgs/msg/Image", "/camera/image_raw", lambda m: self._on_image("color", m),
            CAMERA_QOS)
        self.sub_depth = node.create_subscription(
            "sensor_msgs/msg/Image", "/camera/depth/image_raw",
            lambda m: self._on_image("depth", m), CAMERA_QOS)
        node.create_subscription("sensor_msgs/msg/CameraInfo", "/camera/camera_info",
                                 self._on_camera_info, CAMERA_QOS)
        node.create_subscription("twinslam_msgs/msg/UploadRequest", "/edge/upload_request",
                                 self._on_upload_request, PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/MapUpdate", "/edge/map_update",
                                 self._on_map_update, node_runtime.LATCHED)
        node.create_timer(0.5, self._check_edge)
        self._uploader = threading.Thread(target=self._upload_loop, name="uplink", daemon=True)
        self._uploader.start()

    def _make_shaper(self, p: dict[str, Any]) -> UplinkShaper | TcShaper:
        kind = str(p["shaper"])
        if kind == "token_bucket":
            return UplinkShaper()
        if kind != "tc":
            raise ValueError(f"shaper must be one of {', '.join(SHAPERS)}, got {kind!r}")
        netem = NetemConfig(float(p["netem_delay_ms"]), float(p["netem_loss_percent"]))
        shaper = TcShaper(str(p["uplink_interface"]), netem,
                          flush=lambda: self.pub_keyframes.wait_for_acknowledgments(
                              WRITE_RETRY_S))
        shaper.start(float(self.channel.rates[0]))
        return shaper

    # -- camera ------------------------------------------------------------------------------

    def _on_camera_info(self, msg: Any) -> None:
        if self.core is None:
            k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
            self.core = DeviceTrackerCore(k, self.slot_frames, self.tracking_config,
                                          self.keep_slots)
            self.node.get_logger().info(f"camera {msg.width}x{msg.height}, fx {k[0, 0]:.1f}; "
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
                self.node.get_logger().warning(
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
            self.node.get_logger().error(f"frame skipped: {exc}")
            return
        stamp = stamp_seconds(color_msg.header)
        with self._lock:
            was_lost = self.core.lost
            result = self.core.track(color, depth, stamp)
        record = result.record
        log = self.node.get_logger()
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
        pose = set_header(new("geometry_msgs/msg/PoseStamped", pose=pose_msg(record.pose)),
                          stamp, self.map_frame)
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
        path = new("nav_msgs/msg/Path", poses=list(self.path))
        self.pub_path.publish(set_header(path, stamp, self.map_frame))
        tracked = sum(f.tracked for f in frames)
        self.node.get_logger().info(
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
            self.node.get_logger().debug(f"map version {update.version}: "
                                         f"{len(update.point_ids)} points")

    def _on_upload_request(self, msg: Any) -> None:
        slot = int(msg.slot)
        for answered in [k for k in self._unanswered if k <= slot]:
            del self._unanswered[answered]     # older ones the edge will not answer now
        if self._edge_silent_since is not None:
            self.node.get_logger().info(
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
            self.node.get_logger().warning(
                f"slot {slot}: no upload request from the edge for {waited:.1f} s (link down "
                f"or edge gone?); tracking on the local map (version {version}, {points} "
                "points) until it answers")

    def _encode_keyframe(self, slot: int, frame_id: int) -> tuple[int, bytes, int] | None:
        """(frame id, CDR bytes, bytes the uplink is charged) of a requested frame; None, and
        an error logged, when the device no longer holds it."""
        with self._lock:
            data = self.core.upload(frame_id) if self.core else None
        if data is None:
            self.node.get_logger().error(f"slot {slot}: frame {frame_id} was asked for but is "
                                         "no longer held; not sent")
            return None
        msg = keyframe_message(slot, data.frame_id, data.stamp, data.pose,
                               self.core.k if self.core else np.eye(3), data.keypoints,
                               data.depths, data.descriptors, data.point_ids,
                               image=self.images.get(frame_id))
        payload = self.pub_keyframes.encode(msg)
        return frame_id, payload, max(self.alpha_bytes, len(payload))

    def _publish_keyframe(self, slot: int, frame_id: int, payload: bytes) -> None:
        """Write one keyframe, retrying while the writer is blocked (a reliable writer whose
        readers stopped acknowledging times out after its max blocking time)."""
        deadline = time.monotonic() + WRITE_RETRY_S
        while True:
            try:
                self.pub_keyframes.publish_raw(payload)
                return
            except Exception as exc:           # cyclonedds' DDSException: a write timeout
                if time.monotonic() > deadline:
                    self.node.get_logger().error(
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
            self.pub_throughput.publish(set_header(out, time.time(), ""))

    def close(self) -> None:
        self._uploads.put(None)
        self._uploader.join(timeout=5.0)
        if isinstance(self.shaper, TcShaper):
            self.shaper.close()


def main(args: list[str] | None = None) -> int:
    node = node_runtime.start_node("device_tracker", PARAMETERS, args)
    try:
        device = DeviceTrackerNode(node)
    except (ValueError, ChannelError, ShaperError) as exc:
        return node_runtime.fail(node, str(exc))
    shaper = (f"tc on {device.shaper.interface}" if isinstance(device.shaper, TcShaper)
              else "token bucket")
    node.get_logger().info(f"slots of {device.slot_frames} frames, channel "
                           f"{node.get_parameter('channel').value}, uplink shaper {shaper}; "
                           "waiting for /camera/camera_info")
    node_runtime.run(node, on_exit=device.close)
    return 0


if __name__ == "__main__":
    sys.exit(main())
