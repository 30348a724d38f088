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
from device_tracker.tracking import TrackingConfig
from device_tracker.uplink_shaper import UplinkShaper
from edge_mapper.messages import read_map_update
from msg_schemas import new
from msg_schemas.poses import pose_msg
from node_runtime import PROTOCOL
from sequence_player.messages import set_header
from udt_node.channel import ChannelError, parse_channel

PARAMETERS = {"slot_frames": 60, "alpha_mbit": 5.0, "channel": "markov:N=2",
              "rate_min": 40.0, "rate_max": 80.0, "seed": 0, "n_features": 1000,
              "map_frame": "map"}
#: camera topics: reliable and deep, so a slot's bundle adjustment next door drops no frame
CAMERA_QOS = node_runtime.QoSProfile(depth=60)
MAX_PENDING = 5                     #: colour frames waiting for their depth at most
#: bytes of one keypoint in a features-only keyframe (xy, depth, descriptor, id)
KEYPOINT_BYTES = 8 + 4 + 32 + 8


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
        self.shaper = UplinkShaper()
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
        node.create_subscription("sensor_msgs/msg/Image", "/camera/image_raw",
                                 lambda m: self._on_image("color", m), CAMERA_QOS)
        node.create_subscription("sensor_msgs/msg/Image", "/camera/depth/image_raw",
                                 lambda m: self._on_image("depth", m), CAMERA_QOS)
        node.create_subscription("sensor_msgs/msg/CameraInfo", "/camera/camera_info",
                                 self._on_camera_info, CAMERA_QOS)
        node.create_subscription("twinslam_msgs/msg/UploadRequest", "/edge/upload_request",
                                 self._on_upload_request, PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/MapUpdate", "/edge/map_update",
                                 self._on_map_update, node_runtime.LATCHED)
        self._uploader = threading.Thread(target=self._upload_loop, name="uplink", daemon=True)
        self._uploader.start()

    # -- camera ------------------------------------------------------------------------------

    def _on_camera_info(self, msg: Any) -> None:
        if self.core is None:
            k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
            self.core = DeviceTrackerCore(k, self.slot_frames, self.tracking_config)
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
        self.pub_summaries.publish(frame_summaries_message(slot, rate, state, version, frames,
                                                           stamp))
        path = new("nav_msgs/msg/Path", poses=list(self.path))
        self.pub_path.publish(set_header(path, stamp, self.map_frame))
        tracked = sum(f.tracked for f in frames)
        self.node.get_logger().info(
            f"slot {slot}: {len(frames)} frames ({tracked} tracked, {self.skipped} skipped so "
            f"far), d_k {rate:.1f} Mbit/s, map version {version}, "
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
        self._uploads.put((int(msg.slot), [int(f) for f in msg.upload_frame_ids]))

    def _upload_loop(self) -> None:
        """Sends each slot's requested frames through the shaper, then its throughput."""
        while (job := self._uploads.get()) is not None:
            slot, frame_ids = job
            rate, state = self.slot_rates.get(slot, (self.channel.rates[0], 0))
            self.shaper.start_slot(slot, rate, state)
            for frame_id in frame_ids:
                with self._lock:
                    data = self.core.upload(frame_id) if self.core else None
                if data is None:
                    self.node.get_logger().error(f"slot {slot}: frame {frame_id} was asked "
                                                 "for but is no longer held; not sent")
                    continue
                msg = keyframe_message(slot, data.frame_id, data.stamp, data.pose,
                                       self.core.k if self.core else np.eye(3),
                                       data.keypoints, data.depths, data.descriptors,
                                       data.point_ids)
                size = max(self.alpha_bytes, KEYPOINT_BYTES * len(data.keypoints))
                self.shaper.send(size, lambda m=msg: self.pub_keyframes.publish(m))
            t = self.shaper.end_slot()
            out = new("twinslam_msgs/msg/UplinkThroughput", slot=t.slot,
                      configured_rate_mbps=t.configured_rate_mbps, rate_state=t.rate_state,
                      achieved_mbps=t.achieved_mbps, bytes_sent=t.bytes_sent,
                      duration_s=t.duration_s, frames_sent=t.frames_sent)
            self.pub_throughput.publish(set_header(out, time.time(), ""))

    def close(self) -> None:
        self._uploads.put(None)
        self._uploader.join(timeout=5.0)


def main(args: list[str] | None = None) -> int:
    node = node_runtime.start_node("device_tracker", PARAMETERS, args)
    try:
        device = DeviceTrackerNode(node)
    except (ValueError, ChannelError) as exc:
        return node_runtime.fail(node, str(exc))
    node.get_logger().info(f"slots of {device.slot_frames} frames, channel "
                           f"{node.get_parameter('channel').value}; waiting for "
                           "/camera/camera_info")
    node_runtime.run(node, on_exit=device.close)
    return 0


if __name__ == "__main__":
    sys.exit(main())
