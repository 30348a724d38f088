"""device_tracker: the device's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``camera/image_raw`` + ``camera/depth/image_raw`` (paired by stamp,
  :mod:`device_tracker.frame_pairing`) + ``camera/camera_info`` → every frame tracked against
  the edge's last map alone (``map_source:=edge``, the paper's device) or with the device's own
  recent points too (``edge+local``) (:class:`~device_tracker.device_core.DeviceTrackerCore`);
  ``device/pose`` per frame, ``device/path`` per slot;
* at each slot's end, ``device/frame_summaries`` with d_k drawn from the channel model
  (``channel:=markov:N=2`` or ``trace:FILE``, as the simulator's);
* ``edge/upload_request`` → exactly the frames asked for go out as ``Keyframe`` s on
  ``device/keyframes`` through the uplink shaper on an upload thread
  (:mod:`device_tracker.uplink_sender`), each occupying the link for ``alpha_mbit`` or its real
  size if larger; then the slot's ``device/uplink_throughput``;
* ``edge/map_update`` (transient local) → the new local map.

Topic names are relative (``-r __ns:=/ar1``). ``shaper:=tc`` hands the pacing to the kernel
(:mod:`twinslam.uplink.tc_shaper`); ``upload_image:=true`` sends each keyframe's colour image
too. When the edge stops answering (:mod:`device_tracker.edge_watchdog`) the device says so and
tracks on; a lost frame is relocalised against the local map, and the node logs both ends.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
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
from device_tracker.edge_watchdog import EdgeWatchdog
from device_tracker.frame_pairing import FramePairing
from device_tracker.messages import frame_summaries_message, uplink_throughput_message
from device_tracker.parameters import PARAMETERS
from device_tracker.uplink_sender import Encoded, UplinkSender
from msg_schemas import qos, topics
from msg_schemas.headers import set_header, stamp_key, stamp_seconds
from msg_schemas.poses import pose_msg
from twinslam.node_hosts.acks import wait_for_acks
from twinslam.node_hosts.checked_subscription import CheckedSubscription
from twinslam.node_hosts.node_main import NodeStartError, run_node
from twinslam.node_hosts.parameters import declare
from twinslam.slam.keyframe import keyframe_message
from twinslam.slam.map_update import read_map_update
from twinslam.slam.tracking import TrackingConfig
from twinslam.uplink.channels import ChannelError, initial_rate, parse_channel
from twinslam.uplink.shaper import ShaperError, SlotThroughput
from twinslam.uplink.tc_shaper import NetemConfig, TcShaper, make_shaper

#: how long one keyframe write may keep failing (the writer's history full of unacknowledged
#: keyframes while the link is down) before that keyframe is given up
WRITE_RETRY_S = 30.0


class DeviceTrackerNode(Node):
    def __init__(self) -> None:
        super().__init__("device_tracker")
        p = declare(self, PARAMETERS)
        self.slot_frames = int(p["slot_frames"])
        self.frame_rate_hz = float(p["frame_rate_hz"])
        self.alpha_bytes = int(float(p["alpha_mbit"]) * 1e6 / 8)
        self.channel_spec = str(p["channel"])
        try:
            self.channel = parse_channel(self.channel_spec,
                                         (float(p["rate_min"]), float(p["rate_max"])),
                                         int(p["seed"]))
        except (ChannelError, ValueError) as exc:
            raise NodeStartError(str(exc)) from None
        self.map_frame = str(p["map_frame"])
        self.map_source = str(p["map_source"])
        self.tracking_config = TrackingConfig(n_features=int(p["n_features"]), relocalise=True)
        self.core: DeviceTrackerCore | None = None
        # the publisher the tc shaper flushes exists before the shaper
        self.pub_keyframes = self.create_publisher(Keyframe, topics.KEYFRAMES, qos.PROTOCOL)
        try:
            self.shaper = make_shaper(
                str(p["shaper"]), initial_rate(self.channel), str(p["uplink_interface"]),
                NetemConfig(float(p["netem_delay_ms"]), float(p["netem_loss_percent"])),
                flush=lambda: wait_for_acks(self.pub_keyframes, WRITE_RETRY_S))
        except (ShaperError, ValueError) as exc:
            raise NodeStartError(str(exc)) from None
        self.upload_image = bool(p["upload_image"])
        self.keep_slots = int(p["keep_slots"])   #: 4 ride out a link down for ~5 s
        self.watchdog = EdgeWatchdog(float(p["edge_timeout_s"]))
        self.pairing = FramePairing()
        self.skipped = 0
        self.last_slot = -1                      #: the last slot whose summaries went out
        self.path: list[Any] = []
        DeviceTrackerCore.warm_up()
        self._lock = threading.Lock()            # the core, between the node's callbacks
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
        self.sender = UplinkSender(self.shaper, self._encode_keyframe, self.pub_keyframes.publish,
                                   self._report_throughput, self.get_logger().error,
                                   initial_rate(self.channel), WRITE_RETRY_S)
        self.sender.start()

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    # -- camera ------------------------------------------------------------------------------

    def _on_camera_info(self, msg: Any) -> None:
        if self.core is None:
            k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
            self.core = DeviceTrackerCore(k, self.slot_frames, self.tracking_config,
                                          self.keep_slots, self.frame_rate_hz, self.map_source)
            self.get_logger().info(f"camera {msg.width}x{msg.height}, fx {k[0, 0]:.1f}; "
                                   "tracking starts")
        self._process_ready()

    def _on_image(self, kind: str, msg: Any) -> None:
        self.pairing.add(kind, stamp_key(msg.header), msg)
        self._process_ready()

    def _process_ready(self) -> None:
        if self.core is None:
            return
        for frame in self.pairing.ready():
            if frame.color is None:
                self.skipped += 1
                self.get_logger().warning(
                    f"depth image of stamp {frame.stamp_key / 1e9:.3f} s without its colour "
                    f"image (newest colour {frame.newest_color / 1e9:.3f} s): skipped")
            else:
                self._track(frame.color, frame.depth)

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
        source = str(self.get_parameter("map_source").value)
        with self._lock:
            if source != self.core.map_source:       # set live (ros2 param set)
                self.core.set_map_source(source)
                self.get_logger().info(f"map source {source} from frame "
                                       f"{self.core.frame_count} on")
            # a slot whose last frame never came ends at the first frame of a later slot
            unfinished = self.core.take_slot() if self.core.ends_slot_before(stamp) else []
            result = self.core.track(color, depth, stamp,
                                     image=color_msg if self.upload_image else None)
            finished = self.core.take_slot() if result.slot_done else []
            version = self.core.map_version
        if unfinished:
            self._end_slot(unfinished, version, stamp)
        record = result.record
        if result.lost_now:
            self.get_logger().warning(f"frame {record.frame_id}: tracking lost; relocalising "
                                      "against the local map")
        elif result.recovered:
            self.get_logger().info(f"frame {record.frame_id}: relocalised")
        pose = set_header(PoseStamped(pose=pose_msg(record.pose)), stamp, self.map_frame)
        self.pub_pose.publish(pose)
        self.path.append(pose)
        if finished:
            self._end_slot(finished, version, stamp)

    def _end_slot(self, frames: list[Any], version: int, stamp: float) -> None:
        assert self.core is not None
        slot = frames[-1].slot
        for _ in range(max(slot - self.last_slot, 1)):   # on through slots no frame reached
            state, rate = self.channel.step()
        self.last_slot = slot
        self.sender.rates[slot] = (rate, state)
        self.watchdog.asked(slot)
        self.pub_summaries.publish(frame_summaries_message(slot, rate, state, version, frames,
                                                           stamp))
        self.pub_path.publish(set_header(Path(poses=list(self.path)), stamp, self.map_frame))
        self.get_logger().info(
            f"slot {slot}: {len(frames)} frames ({sum(f.tracked for f in frames)} tracked, "
            f"{self.skipped} skipped so far; {self.sub_color.received} colour / "
            f"{self.sub_depth.received} depth images received), d_k {rate:.1f} Mbit/s, map "
            f"version {version}, {len(self.core.tracking.map)} local points")

    # -- edge --------------------------------------------------------------------------------

    def _on_map_update(self, msg: Any) -> None:
        if self.core is None:
            return
        update = read_map_update(msg)
        with self._lock:
            applied = self.core.apply_map_update(update, int(msg.slot))
        if applied:
            self.get_logger().debug(f"map version {update.version}: {len(update.point_ids)} "
                                    "points")

    def _on_upload_request(self, msg: Any) -> None:
        slot = int(msg.slot)
        silence = self.watchdog.answered(slot)
        if silence is not None:
            self.get_logger().info(f"slot {slot}: the edge answers again after {silence:.1f} s "
                                   "of silence; uploads resume")
        self.sender.request(slot, [int(f) for f in msg.upload_frame_ids])

    def _check_edge(self) -> None:
        """Say once when the edge stops answering: the device keeps tracking regardless."""
        silent = self.watchdog.check()
        if silent is not None:
            slot, waited = silent
            points = len(self.core.tracking.map) if self.core else 0
            version = self.core.map_version if self.core else 0
            self.get_logger().warning(
                f"slot {slot}: no upload request from the edge for {waited:.1f} s (link down "
                f"or edge gone?); tracking on the local map (version {version}, {points} "
                "points) until it answers")

    def _encode_keyframe(self, slot: int, frame_id: int) -> Encoded | None:
        """A requested frame's bytes on the upload thread; None, and an error logged, when the
        device no longer holds it."""
        core = self.core
        # no lock: a finished frame's upload is never changed, and a dict lookup is atomic;
        # waiting on the tracking thread's lock stalled uploads for seconds on a busy machine
        data = core.upload(frame_id) if core else None
        image = core.upload_image(frame_id) if core else None
        if data is None:
            self.get_logger().error(f"slot {slot}: frame {frame_id} was asked for but is "
                                    "no longer held; not sent")
            return None
        msg = keyframe_message(dataclasses.replace(data, slot=slot), image=image)
        payload = serialize_message(msg)
        return frame_id, payload, max(self.alpha_bytes, len(payload))

    def _report_throughput(self, throughput: SlotThroughput) -> None:
        self.pub_throughput.publish(uplink_throughput_message(throughput, self._now()))

    def close(self) -> None:
        self.sender.close()
        if isinstance(self.shaper, TcShaper):
            self.shaper.close()


def main(args: list[str] | None = None) -> int:
    def started(device: DeviceTrackerNode) -> None:
        shaper = (f"tc on {device.shaper.interface}" if isinstance(device.shaper, TcShaper)
                  else "token bucket")
        device.get_logger().info(
            f"slots of {device.slot_frames} frames "
            f"({device.slot_frames / device.frame_rate_hz:g} s of stamps), map source "
            f"{device.map_source}, channel "
            f"{device.channel_spec}, uplink shaper {shaper}; waiting for "
            f"{device.resolve_topic_name(topics.CAMERA_INFO)}")

    return run_node("device_tracker", DeviceTrackerNode, args, started=started)


if __name__ == "__main__":
    sys.exit(main())
