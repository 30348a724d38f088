"""sequence_player: replays an RGB-D sequence (a SUN3D / 7-Scenes / TUM RGB-D folder, or a
rosbag2 MCAP recorded with ``twinslam record``) as ROS 2 camera topics.

Publishes, per frame and with the frame's recorded time (shifted to the node clock's now) in
every header:

* ``camera/image_raw`` — ``sensor_msgs/Image``, ``rgb8`` (``mono8`` with ``mono:=true``)
* ``camera/depth/image_raw`` — ``16UC1`` millimetres or ``32FC1`` metres (``depth_encoding``)
* ``camera/camera_info`` — ``sensor_msgs/CameraInfo``
* ``camera/ground_truth_pose`` — ``geometry_msgs/PoseStamped`` in ``world`` when the dataset
  has ground truth (for evaluation only; nothing in the pipeline subscribes to it), and
  ``camera/ground_truth_path`` — ``nav_msgs/Path`` of the newest ``path_window`` of them, once
  a second and at the end, latched (for a viewer, beside ``device/path``); and ``world`` →
  ``map`` on ``/tf_static`` from the first played frame's ground truth, which is where a device
  that starts with that frame puts its map's origin (``map_frame:=''`` turns it off)

at the recorded rate × ``rate``, frames [``start``, ``end``), once or with ``loop``, forward or
``order:=forward_backward``, with ``blank:=START:COUNT`` bursts of covered-lens frames, one
frame in ``every`` from ``phase`` (devices replaying one walk without sharing an image)
(:mod:`twinslam.sequence_player.playback`: the scenarios where the edge's map matters), until
``stop_after`` frames are published where it is set — also while playing (``ros2 param set
/sequence_player stop_after N``): a run that waits for an event plays on until it came, then
ends at a slot's end of its choosing (:mod:`twinslam.live.playback_end`). Topic names
are relative: ``-r __ns:=/ar1`` plays into ``/ar1/camera/...``. ``wait_for_subscribers:=N``
holds the first frame until N subscribers match the colour topic (DDS does not deliver what was
published before a reader matched), then ``DISCOVERY_SETTLE_S`` more: the writer learning of a
reader does not mean the reader has learnt of the writer (nor that the depth and camera-info
readers have matched), and a reader drops samples of a writer it does not know yet.
``start_delay_s`` holds it that much longer: a user who comes to the place after the others.
``pace_frames:=N`` makes the camera wait for its device (:mod:`twinslam.sequence_player.pacing`):
at most N published frames are left for the device to pose (the next waits while N are), the
recording's clock stopped meanwhile — every frame tracked on a machine too slow for real time;
with ``pace_group:=NAME`` the paced cameras of a fleet keep one recording clock, each waiting
while any device of the group is behind (``/playback_pace/NAME``).
A corrupt image is skipped, counted and named in a warning; the run goes on. Every few seconds
and at the end it says on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``) what it
published and skipped — a run's monitor reads the skipped frames there — logs it, and exits 0.
``sequence:=synthetic[:frames]`` (the default) renders the textured room of
:mod:`twinslam.sequences.synthetic_worlds` with exact depth and ground truth,
``synthetic-corridor[:frames]`` its corridor walked out and back.
"""

from __future__ import annotations

from typing import NoReturn

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from tf2_msgs.msg import TFMessage
from twinslam_msgs.msg import PlaybackPace

from msg_schemas import qos, topics
from msg_schemas.headers import ros_duration, stamp_key, stamp_seconds, time_seconds
from msg_schemas.paths import PathWindow
from msg_schemas.transforms import tf_message, transform_stamped
from twinslam.node_runtime.acks import wait_for_acks
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.node_main import NodeStartError, exit_process, run_node
from twinslam.node_runtime.parameters import declare
from twinslam.sequence_player.messages import (
    camera_info_message,
    color_message,
    depth_message,
    playback_status,
    pose_message,
)
from twinslam.sequence_player.pacing import DevicePacing
from twinslam.sequence_player.parameters import PARAMETERS
from twinslam.sequence_player.playback import Playback, PlayedSequence, parse_bursts
from twinslam.sequences.decoded_frames import DecodedFrameCache
from twinslam.sequences.frame import RgbdFrame, SequenceError
from twinslam.sequences.opening import open_sequence

PROGRESS_EVERY_S = 5.0
#: camera/ground_truth_path goes out once this many frames (a second at 30 Hz) and at the end
PATH_EVERY_FRAMES = 30
DISCOVERY_SETTLE_S = 1.0
POLL_S = 0.05
#: a paced player plays on in real time after this long without a pose from its device
PACE_GIVE_UP_S = 60.0


class SequencePlayer(Node):
    """Publishes one frame per timer tick, each at its recorded time (``rate`` × faster)."""

    def __init__(self) -> None:
        super().__init__("sequence_player")
        p = declare(self, PARAMETERS)
        try:
            # frames played in an earlier run (or pass) read back decoded, where the
            # environment names a cache (TWINSLAM_FRAME_CACHE)
            sequence = open_sequence(p["sequence"], p["start"], p["end"],
                                     str(p["colour_intrinsics"]),
                                     frame_cache=DecodedFrameCache.from_environment())
            playback = Playback(str(p["order"]), parse_bursts(p["blank"]), int(p["every"]),
                                int(p["phase"]))
            self.reader = PlayedSequence(sequence, playback)
        except (SequenceError, ValueError) as exc:
            raise NodeStartError(str(exc)) from None
        self.rate, self.loop = float(p["rate"]), bool(p["loop"])
        self.stop_after = int(p["stop_after"])         #: 0: no limit
        self.depth_encoding, self.mono = str(p["depth_encoding"]), bool(p["mono"])
        self.frame_id, self.world_frame_id = str(p["frame_id"]), str(p["world_frame_id"])
        self.pub_color = self.create_publisher(Image, topics.CAMERA_IMAGE, qos.CAMERA)
        self.pub_depth = self.create_publisher(Image, topics.CAMERA_DEPTH, qos.CAMERA)
        self.pub_info = self.create_publisher(CameraInfo, topics.CAMERA_INFO, qos.CAMERA)
        self.pub_pose = self.create_publisher(PoseStamped, topics.GROUND_TRUTH_POSE, qos.CAMERA)
        self.pub_path = self.create_publisher(Path, topics.GROUND_TRUTH_PATH, qos.MAP)
        self.path = PathWindow(int(p["path_window"]))
        self.map_frame = str(p["map_frame"])
        if self.map_frame == self.world_frame_id:
            raise NodeStartError(f"map_frame and world_frame_id are both {self.map_frame!r}: "
                                 "the map's anchor needs two frames")
        self.pub_static = (self.create_publisher(TFMessage, topics.TF_STATIC, qos.TF_STATIC)
                           if self.map_frame else None)
        self.pub_status = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                qos.PROTOCOL)
        self.sequence = str(p["sequence"])
        self.anchored = False                 #: world -> map went out
        self.published = 0
        self.skipped = 0
        self.finished = False
        self._frames = iter(self.reader)
        self._first_stamp = self.reader.first_stamp
        self._lap_offset = 0.0        # recorded seconds added per completed loop
        self._next = self._read_next()        # the first frame read before the clock starts
        #: the recording's clock starts this long after the player is ready to play
        self._delay_ns = round(float(p["start_delay_s"]) * 1e9)
        self._start_ns = self._now_ns() + self._delay_ns
        self._last_progress = self._start_ns
        self._wait_for = int(p["wait_for_subscribers"])
        self.pacing = DevicePacing(int(p["pace_frames"]), PACE_GIVE_UP_S)
        if self.pacing.active:
            self.sub_pose = self.create_subscription(PoseStamped, topics.DEVICE_POSE,
                                                     self._on_device_pose, qos.PROTOCOL)
        self.pace_group = str(p["pace_group"])
        self.pub_pace = None
        self._told = (0.0, False)             #: what the group was last told
        if self.pace_group:
            if not self.pacing.window:
                raise NodeStartError(f"pace_group:={self.pace_group} needs pace_frames: a "
                                     "camera that does not wait for its device has no held "
                                     "time to share")
            topic = f"{topics.PLAYBACK_PACE}/{self.pace_group}"
            self.pub_pace = self.create_publisher(PlaybackPace, topic, qos.PACE)
            self.sub_pace = CheckedSubscription(self, PlaybackPace, topic, self._on_group_said,
                                                qos.PACE)
        self._settling = False
        self.timer = self.create_timer(POLL_S, self._tick)
        self.add_on_set_parameters_callback(self._stop_after_refused)
        self.add_post_set_parameters_callback(self._stop_after_set)
        if self._wait_for > 0:
            self.get_logger().info(f"waiting for {self._wait_for} subscriber(s) on "
                                   f"{self.pub_color.topic_name}")
        else:
            self._schedule()

    def _stop_after_refused(self, params: list[Parameter]) -> SetParametersResult:
        """A ``stop_after`` below the frames already published cannot be honoured: refused
        with the count, so a caller can choose a later one."""
        for param in params:
            if param.name == "stop_after" and 0 < int(param.value) < self.published:
                return SetParametersResult(
                    successful=False, reason=f"stop_after := {param.value}: {self.published} "
                    "frames are published already")
        return SetParametersResult(successful=True)

    def _stop_after_set(self, params: list[Parameter]) -> None:
        """Apply a new ``stop_after``; one just reached ends the playback now."""
        for param in params:
            if param.name == "stop_after":
                self.stop_after = int(param.value)
                self.get_logger().info(
                    f"stopping after {self.stop_after} frames ({self.published} published)"
                    if self.stop_after else "playing without a frame limit")
                if self._limit_reached() and self._next is not None and not self._wait_for:
                    self._next = None
                    self._schedule()

    def _limit_reached(self) -> bool:
        return 0 < self.stop_after <= self.published

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _read_next(self) -> RgbdFrame | None:
        frame = next(self._frames, None)
        if frame is None:
            self.skipped += len(self.reader.skipped)
            if self.loop and self.published:
                self._lap_offset += self.reader.span_s + self.reader.period_s
                self._frames = iter(self.reader)
                frame = next(self._frames, None)
        return frame

    def _recorded(self, frame: RgbdFrame) -> float:
        return frame.stamp - self._first_stamp + self._lap_offset

    def _stamp_ns(self, frame: RgbdFrame) -> int:
        """The frame's stamp: its time in the recording, from the playback's start."""
        return self._start_ns + round(self._recorded(frame) / self.rate * 1e9)

    def _due_ns(self, frame: RgbdFrame) -> int:
        """When the frame goes out: at its stamp, later by the time a paced playback held."""
        return self._stamp_ns(frame) + round(self.pacing.held_s * 1e9)

    def _on_device_pose(self, msg: PoseStamped) -> None:
        held = self.pacing.holding
        self.pacing.posed(stamp_key(msg.header), self._now_ns() * 1e-9)
        if held:
            self._fire_in(0)                  # the held frame may go now

    def _on_group_said(self, msg: PlaybackPace) -> None:
        if msg.camera != self.get_fully_qualified_name():
            self.pacing.group_said(msg.camera, time_seconds(msg.held),
                                   msg.waiting_for_device, self._now_ns() * 1e-9)

    def _tell_group(self, now_s: float) -> None:
        """Tell the group how long this camera has held and whether it waits for its device,
        where that changed."""
        told = self.pacing.told(now_s)
        if self.pub_pace is None or told == self._told:
            return
        self._told = told
        held, waiting = told
        self.pub_pace.publish(PlaybackPace(camera=self.get_fully_qualified_name(),
                                           held=ros_duration(held), waiting_for_device=waiting))

    def _fire_in(self, delay_ns: int) -> None:
        """Make the one timer fire once ``delay_ns`` from now (then periodically, until the
        next call moves it again)."""
        self.timer.timer_period_ns = max(delay_ns, 1_000_000)
        self.timer.reset()

    def _schedule(self) -> None:
        if self._next is None:
            self.timer.cancel()
            self._finish()
            return
        self._fire_in(self._due_ns(self._next) - self._now_ns())

    def _tick(self) -> None:
        if self._wait_for > 0:
            if self.pub_color.get_subscription_count() >= self._wait_for:
                self._wait_for = 0            # matched both ways once settled
                self._settling = True
                self._fire_in(round(DISCOVERY_SETTLE_S * 1e9))
            return
        if self._settling:                    # the recording starts now (or after the delay)
            self._settling = False
            self._start_ns = self._now_ns() + self._delay_ns
            self._schedule()
            return
        frame = self._next
        if frame is None:
            return
        if self._due_ns(frame) > self._now_ns() + 1_000_000:
            self._schedule()                  # woke early (a periodic tick): wait on
            return
        if not self._paced_may_publish():
            return
        stamp = self._stamp_ns(frame) * 1e-9
        color = color_message(frame, stamp, self.frame_id, self.mono)
        # by the header's own nanoseconds, which the device's pose repeats
        self.pacing.published(stamp_key(color.header))
        self.pub_color.publish(color)
        if frame.depth is not None:
            self.pub_depth.publish(depth_message(frame, stamp, self.frame_id,
                                                 self.depth_encoding))
        self.pub_info.publish(camera_info_message(frame, stamp, self.frame_id))
        if frame.pose is not None:
            if self.pub_static is not None and not self.anchored:   # the first ground truth
                self.pub_static.publish(tf_message(transform_stamped(
                    frame.pose, stamp, self.world_frame_id, self.map_frame)))
                self.anchored = True
            pose = pose_message(frame.pose, stamp, self.world_frame_id)
            self.pub_pose.publish(pose)
            self.path.add(pose)
        self.published += 1
        if self.published % PATH_EVERY_FRAMES == 0:
            self._publish_path()
        now = self._now_ns()
        if now - self._last_progress >= PROGRESS_EVERY_S * 1e9:
            self._last_progress = now
            self.get_logger().info(
                f"frame {frame.index + 1}/{len(self.reader)} ({self.published} published, "
                f"{self.skipped + len(self.reader.skipped)} skipped)")
            self._publish_status(self.skipped + len(self.reader.skipped), finished=False)
        self._next = None if self._limit_reached() else self._read_next()
        self._schedule()

    def _paced_may_publish(self) -> bool:
        """Whether the device is near enough to its camera for the next frame, and the
        group's clock as far as this one's; a holding player looks again at every pose, every
        ``POLL_S`` and where the group's hold ends."""
        gave_up = self.pacing.gave_up
        now = self._now_ns() * 1e-9
        may = self.pacing.may_publish(now)
        self._tell_group(now)                 # also while holding: the group holds with it
        if not may:
            group_wait = self.pacing.group_wait_s(now)
            self._fire_in(round(min(POLL_S, group_wait) * 1e9 if group_wait > 0
                                else POLL_S * 1e9))
            return False
        if self.pacing.gave_up and not gave_up:
            self.get_logger().warning(
                f"no pose from the device on {self.sub_pose.topic_name} for "
                f"{PACE_GIVE_UP_S:.0f} s: playing on in real time")
        return True

    def _publish_path(self) -> None:
        if self.path.poses:                   # stamped as its newest pose
            newest = stamp_seconds(self.path.poses[-1].header)
            self.pub_path.publish(self.path.message(newest, self.world_frame_id))

    def _publish_status(self, skipped: int, finished: bool) -> None:
        """Playback so far on /diagnostics (what a run's monitor counts skipped frames by)."""
        self.pub_status.publish(playback_status(self.published, skipped,
                                                list(self.reader.skipped), finished,
                                                self._now_ns() * 1e-9, self.sequence))

    def _finish(self) -> None:
        self.finished = True
        self._publish_path()
        self._publish_status(self.skipped, finished=True)
        elapsed = (self._now_ns() - self._start_ns) * 1e-9
        # the last frames may still be in flight: let reliable readers acknowledge them before
        # the process (and its participant) goes away
        for pub in (self.pub_color, self.pub_depth, self.pub_info, self.pub_pose, self.pub_path,
                    self.pub_static, self.pub_status):
            if pub is not None:
                wait_for_acks(pub, 2.0)
        skipped = f" ({', '.join(self.reader.skipped)})" if self.reader.skipped else ""
        group = f" and its group {self.pace_group}" if self.pace_group else ""
        paced = (f", {self.pacing.held_s:.1f} s of it held for the device{group}"
                 if self.pacing.window else "")
        self.get_logger().info(f"done: {self.published} frames published in {elapsed:.1f} s"
                               f"{paced}, {self.skipped} skipped{skipped}")


def main(args: list[str] | None = None) -> NoReturn:
    def started(player: SequencePlayer) -> None:
        reader = player.reader
        player.get_logger().info(
            f"playing {len(reader)} frames of {reader.kind} sequence {reader.path} at "
            f"{player.rate}x{' in a loop' if player.loop else ''}"
            f"{f', stopping after {player.stop_after}' if player.stop_after else ''}, order "
            f"{reader.playback.order}"
            + (f", one frame in {reader.playback.every} from {reader.playback.phase}"
               if reader.playback.every > 1 else "")
            + (f", blanked {reader.playback.blank}" if reader.playback.blank else ""))

    exit_process(run_node("sequence_player", SequencePlayer, args,
                          until=lambda player: player.finished, started=started))


if __name__ == "__main__":
    main()
