"""device_tracker: the device side of the slot protocol as a ROS 2 node (docs/architecture.md §1).

* ``camera/image_raw`` + ``camera/depth/image_raw`` (paired by stamp,
  :mod:`device_tracker.frame_pairing`) + ``camera/camera_info`` → every frame tracked against
  the edge's last map alone (``map_source:=edge``, the paper's device) or with the device's own
  recent points too (``edge+local``) (:class:`~device_tracker.device_core.DeviceTrackerCore`),
  on a tracking thread of its own: the executor only takes the images in, so a device whose
  tracking falls behind its camera still takes the edge's requests and map updates as they
  come (tracked on the executor, they waited behind every queued image: on a loaded 2-core
  host a request reached the device 10 s late and the edge closed the slot without its
  keyframes, slot after slot);
  ``device/pose``, ``device/path``, ``device/odom`` and REP 105's ``map`` → ``odom`` →
  camera on ``/tf`` for viewers
  (:mod:`device_tracker.pose_outputs`);
* at each slot's end, ``device/frame_summaries`` with d_k drawn from the channel model
  (``channel:=markov:N=2`` or ``trace:FILE``, as the simulator's);
* ``edge/upload_request`` → exactly the frames asked for go out as ``Keyframe`` s on
  ``device/keyframes`` through the uplink shaper on an upload thread
  (:mod:`device_tracker.uplink_sender`), each occupying the link for ``alpha_mbit`` or its real
  size if larger; then the slot's ``device/uplink_throughput``;
* ``edge/map_update`` (transient local) → the new local map; while lost, the lost frame's
  features up the same uplink to the edge (:mod:`device_tracker.relocalisation_requests`).

Topic names are relative (``-r __ns:=/ar1``). ``shaper:=tc`` hands the pacing to the kernel
(:mod:`twinslam.uplink.tc_shaper`); ``upload_image:=true`` sends each keyframe's colour image
too. When the edge stops answering (:mod:`device_tracker.edge_watchdog`) the device says so and
tracks on; a lost frame is relocalised against the local map, and the node logs both ends.
"""

from __future__ import annotations

import sys
import threading
import traceback
from typing import NoReturn

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from twinslam_msgs.msg import FrameSummaries, Keyframe, MapUpdate, UplinkThroughput, UploadRequest

from device_tracker.camera_input import CameraFrame, CameraIntake
from device_tracker.device_core import DeviceTrackerCore
from device_tracker.edge_watchdog import EdgeWatchdog
from device_tracker.frame_log import frame_log_lines
from device_tracker.map_frame_name import MapFrameName
from device_tracker.messages import (
    FrameRecord,
    encoded_keyframe,
    frame_summaries_message,
    read_map_update,
    uplink_throughput_message,
)
from device_tracker.parameters import PARAMETERS, DeviceSettings
from device_tracker.pose_outputs import PoseOutputs
from device_tracker.relocalisation_requests import EdgeRelocalisation
from device_tracker.uplink_sender import Encoded, UplinkSender
from device_tracker.uplink_setup import uplink_from_parameters
from msg_schemas import qos, topics
from twinslam.node_runtime.acks import wait_for_acks
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.node_main import NodeStartError, exit_process, run_node
from twinslam.node_runtime.parameters import declare
from twinslam.uplink.channels import initial_rate
from twinslam.uplink.shaper import SlotThroughput
from twinslam.uplink.tc_shaper import TcShaper

#: how long one keyframe write may keep failing (the writer's history full of unacknowledged
#: keyframes while the link is down) before that keyframe is given up
WRITE_RETRY_S = 30.0
#: how long the tracking thread may hold the interpreter while the executor waits for it
#: (Python's default: 5 ms): the executor takes three samples a frame (colour, depth, camera
#: info), and at 5 ms a turn it took them no faster than the tracker tracked
SWITCH_INTERVAL_S = 0.0005


class DeviceTrackerNode(Node):
    def __init__(self) -> None:
        super().__init__("device_tracker")
        p = declare(self, PARAMETERS)
        self.core: DeviceTrackerCore | None = None
        # the publisher the tc shaper flushes exists before the shaper
        self.pub_keyframes = self.create_publisher(Keyframe, topics.KEYFRAMES, qos.PROTOCOL)
        try:
            self.settings = s = DeviceSettings.from_parameters(p)
            self.channel, self.shaper = uplink_from_parameters(
                p, flush=lambda: wait_for_acks(self.pub_keyframes, WRITE_RETRY_S))
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None
        self.watchdog = EdgeWatchdog(float(p["edge_timeout_s"]))
        self.camera = CameraIntake()
        #: the camera intake's lock, and the tracking thread's wake-up when frames come
        self._intake = threading.Condition()
        #: set by close(): read by the tracking thread before each frame
        self._stopping = threading.Event()
        #: frames taken from the intake that the tracking thread left when the node stopped
        self.left_untracked = 0
        #: what ended the tracking thread, if it failed (the node then stops: :func:`main`)
        self.failure: BaseException | None = None
        self.last_slot = -1                      #: the last slot whose summaries went out
        DeviceTrackerCore.warm_up()
        self._lock = threading.Lock()            # the core, between the node's callbacks
        self.poses = PoseOutputs(self, s)
        #: the frame each map version's poses go out in (another place's after a merge)
        self.frame_names = MapFrameName(s.map_frame)
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
        self.edge_relocalisation = EdgeRelocalisation(self, s.reloc_period_s, self.sender,
                                                      lambda: self.last_slot)
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self._tracking = threading.Thread(target=self._track_frames, name="tracking",
                                          daemon=True)
        self._tracking.start()

    # -- camera ------------------------------------------------------------------------------

    def _on_camera_info(self, msg: CameraInfo) -> None:
        if self.core is not None:
            return
        k = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
        s = self.settings
        core = DeviceTrackerCore(k, s.slot_frames, s.tracking, s.keep_slots, s.frame_rate_hz,
                                 s.map_source, s.own_map_after)
        with self._intake:
            self.core = core
            self._intake.notify()
        self.get_logger().info(f"camera {msg.width}x{msg.height}, fx {k[0, 0]:.1f}; "
                               "tracking starts")

    def _on_image(self, kind: str, msg: Image) -> None:
        with self._intake:
            self.camera.add(kind, msg)
            self._intake.notify()

    def _track_frames(self) -> None:
        """The tracking thread: the frames complete so far, oldest first, until the node
        closes. A failure is logged with its traceback and stops the node."""
        try:
            while True:
                with self._intake:
                    while True:              # a new image (or the stop) is what can change it
                        if self._stopping.is_set():
                            return
                        core = self.core
                        frames = [] if core is None else list(
                            self.camera.frames(self.get_logger().warning))
                        if frames:
                            break
                        self._intake.wait()
                assert core is not None
                for done, frame in enumerate(frames):
                    if self._stopping.is_set():  # no backlog tracked once the node stops:
                        self.left_untracked = len(frames) - done    # its publishers go next
                        return
                    self._track(core, frame)
        except BaseException as exc:
            self.failure = exc
            self.get_logger().fatal("the tracking thread failed:\n" + "".join(
                traceback.format_exception(exc)))

    def _track(self, core: DeviceTrackerCore, frame: CameraFrame) -> None:
        source, stamp = str(self.get_parameter("map_source").value), frame.stamp
        with self._lock:
            if source != core.map_source:       # set live (ros2 param set)
                core.set_map_source(source)
                self.get_logger().info(f"map source {source} from frame {core.frame_count} on")
            step = core.step(frame.color, frame.depth, stamp,
                             image=frame.color_msg if self.settings.upload_image else None)
        if step.unfinished:
            self._end_slot(step.unfinished, step.map_version, stamp)
        result, record = step.result, step.result.record
        for line in frame_log_lines(result):      # one call site a severity (rclpy's rule)
            if line.warning and line.throttled:    # a state that may repeat a frame
                self.get_logger().warning(line.text, throttle_duration_sec=1.0)
            elif line.warning:
                self.get_logger().warning(line.text)
            elif line.throttled:
                self.get_logger().info(line.text, throttle_duration_sec=1.0)
            else:
                self.get_logger().info(line.text)
        if self.edge_relocalisation.due(record.tracked or result.on_probation, stamp):
            self.edge_relocalisation.ask(core.upload(record.frame_id), stamp,
                                         frame.color_msg.header.frame_id)
        self.poses.frame(record, stamp, frame.color_msg.header.frame_id,
                         self.frame_names.of(record.map_version))
        if step.finished:
            self._end_slot(step.finished, step.map_version, stamp)

    def _end_slot(self, frames: list[FrameRecord], version: int, stamp: float) -> None:
        assert self.core is not None
        slot = frames[-1].slot
        for _ in range(max(slot - self.last_slot, 1)):   # on through slots no frame reached
            state, rate = self.channel.step()
        self.last_slot = slot
        self.sender.rates[slot] = (rate, state)
        self.watchdog.asked(slot)
        self.pub_summaries.publish(frame_summaries_message(slot, rate, state, version, frames,
                                                           stamp))
        self.poses.slot_end(stamp)
        self.get_logger().info(
            f"slot {slot}: {len(frames)} frames ({sum(f.tracked for f in frames)} tracked, "
            f"{self.camera.skipped} skipped so far; {self.sub_color.received} colour / "
            f"{self.sub_depth.received} depth images received), d_k {rate:.1f} Mbit/s, map "
            f"version {version}, {len(self.core.tracking.map)} local points")

    # -- edge --------------------------------------------------------------------------------

    def _on_map_update(self, msg: MapUpdate) -> None:
        update = read_map_update(msg)
        with self._lock:
            if self.core is not None and self.core.apply_map_update(update, int(msg.slot)):
                self.frame_names.applied(update.version, update.frame_id)
                self.get_logger().debug(f"map version {update.version}: "
                                        f"{len(update.point_ids)} points")

    def _on_upload_request(self, msg: UploadRequest) -> None:
        slot = int(msg.slot)
        silence = self.watchdog.answered(slot)
        if silence is not None:
            self.get_logger().info(f"slot {slot}: the edge answers again after {silence:.1f} s "
                                   "of silence; uploads resume")
        self.sender.request(slot, [int(f) for f in msg.upload_frame_ids])

    def _check_edge(self) -> None:
        """Say once when the edge stops answering: the device keeps tracking regardless."""
        if (silent := self.watchdog.check()) is not None:
            (slot, waited), core = silent, self.core
            self.get_logger().warning(
                f"slot {slot}: no upload request from the edge for {waited:.1f} s (link down "
                f"or edge gone?); tracking on the local map (version "
                f"{core.map_version if core else 0}, {len(core.tracking.map) if core else 0} "
                "points) until it answers")

    def _encode_keyframe(self, slot: int, frame_id: int) -> Encoded | None:
        """A requested frame's bytes on the upload thread; None, and an error logged, when the
        device no longer holds it."""
        # no lock: a finished frame's upload is never changed, and a dict lookup is atomic;
        # waiting on the tracking thread's lock stalled uploads for seconds on a busy machine
        core = self.core
        encoded = encoded_keyframe(core.upload(frame_id) if core else None,
                                   core.upload_image(frame_id) if core else None, slot,
                                   self.settings.alpha_bytes)
        if encoded is None:
            self.get_logger().error(f"slot {slot}: frame {frame_id} was asked for but is "
                                    "no longer held; not sent")
        return encoded

    def _report_throughput(self, throughput: SlotThroughput) -> None:
        now = self.get_clock().now().nanoseconds * 1e-9
        self.pub_throughput.publish(uplink_throughput_message(throughput, now))

    def close(self) -> None:
        with self._intake:
            self._stopping.set()
            self._intake.notify()
        self._tracking.join(timeout=10.0)        # the frame being tracked, not those waiting
        with self._intake:
            left = self.left_untracked + len(self.camera.pairing.pending)
        if left:
            self.get_logger().info(f"stopping {left} camera frame(s) behind: not tracked")
        self.sender.close()
        if isinstance(self.shaper, TcShaper):
            self.shaper.close()


def main(args: list[str] | None = None) -> NoReturn:
    devices: list[DeviceTrackerNode] = []

    def started(device: DeviceTrackerNode) -> None:
        devices.append(device)
        shaper = (f"tc on {device.shaper.interface}" if isinstance(device.shaper, TcShaper)
                  else "token bucket")
        device.get_logger().info(f"{device.settings.describe(shaper)}; waiting for "
                                 f"{device.resolve_topic_name(topics.CAMERA_INFO)}")

    code = run_node("device_tracker", DeviceTrackerNode, args,
                    until=lambda device: device.failure is not None, started=started)
    exit_process(1 if code == 0 and any(d.failure is not None for d in devices) else code)


if __name__ == "__main__":
    main()
