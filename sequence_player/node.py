"""sequence_player: replays an RGB-D sequence (a SUN3D / 7-Scenes / TUM RGB-D folder, or a
rosbag2 MCAP recorded with ``twinslam record``) as ROS 2 camera topics.

Publishes, per frame and with the frame's recorded time (shifted to now) in every header:

* ``/camera/image_raw`` — ``sensor_msgs/Image``, ``rgb8`` (``mono8`` with ``mono:=true``)
* ``/camera/depth/image_raw`` — ``16UC1`` millimetres or ``32FC1`` metres (``depth_encoding``)
* ``/camera/camera_info`` — ``sensor_msgs/CameraInfo``
* ``/camera/ground_truth_pose`` — ``geometry_msgs/PoseStamped`` in ``world`` when the dataset
  has ground truth (for evaluation only; nothing in the pipeline subscribes to it)

at the recorded rate × ``rate``, frames [``start``, ``end``), once or with ``loop``;
``wait_for_subscribers:=N`` holds the first frame until N subscribers match the colour topic
(DDS does not deliver what was published before a reader matched), then
``DISCOVERY_SETTLE_S`` more: the writer learning of a reader does not mean the reader has
learnt of the writer (nor that the depth and camera-info readers have matched), and a reader
drops samples of a writer it does not know yet. A corrupt
image is skipped, counted and named in a warning; the run goes on. At the end it logs what it
published and exits 0. ``sequence:=synthetic[:frames]`` (the default) renders the textured
room of :mod:`sequence_player.synthetic` with exact depth and ground truth.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator

import node_runtime
from sequence_player.messages import (
    camera_info_message,
    color_message,
    depth_message,
    pose_message,
)
from sequence_player.readers import RgbdFrame, SequenceError, SequenceReader, open_sequence

PARAMETERS = {"sequence": "synthetic", "rate": 1.0, "loop": False, "start": 0, "end": -1,
              "depth_encoding": "16UC1", "mono": False, "frame_id": "camera",
              "world_frame_id": "world", "wait_for_subscribers": 0}
PROGRESS_EVERY_S = 5.0
DISCOVERY_SETTLE_S = 1.0


class SequencePlayer:
    """Publishes one frame per timer tick, each at its recorded time (``rate`` × faster)."""

    def __init__(self, node: node_runtime.Node, reader: SequenceReader) -> None:
        self.node = node
        self.reader = reader
        p = {k: node.get_parameter(k).value for k in PARAMETERS}
        if not p["rate"] > 0:
            raise SequenceError(f"rate must be > 0, got {p['rate']}")
        self.rate, self.loop = float(p["rate"]), bool(p["loop"])
        self.depth_encoding, self.mono = str(p["depth_encoding"]), bool(p["mono"])
        self.frame_id, self.world_frame_id = str(p["frame_id"]), str(p["world_frame_id"])
        qos = node_runtime.DEFAULT
        self.pub_color = node.create_publisher("sensor_msgs/msg/Image", "/camera/image_raw", qos)
        self.pub_depth = node.create_publisher("sensor_msgs/msg/Image",
                                               "/camera/depth/image_raw", qos)
        self.pub_info = node.create_publisher("sensor_msgs/msg/CameraInfo",
                                              "/camera/camera_info", qos)
        self.pub_pose = node.create_publisher("geometry_msgs/msg/PoseStamped",
                                              "/camera/ground_truth_pose", qos)
        self.published = 0
        self.skipped = 0
        self.finished = False
        self._frames: Iterator[RgbdFrame] = iter(reader)
        self._first_stamp = reader.entries[0].stamp
        self._lap_offset = 0.0        # recorded seconds added per completed loop
        self._start_wall = time.monotonic()
        self._start_ros = time.time()
        self._last_progress = self._start_wall
        self._next = self._read_next()
        self._wait_for = int(p["wait_for_subscribers"])
        self._settling = False
        self.timer = node.create_timer(1.0, self._tick)
        if self._wait_for > 0:
            node.get_logger().info(f"waiting for {self._wait_for} subscriber(s) on "
                                   f"{self.pub_color.topic_name}")
            self.timer.next_due = time.monotonic()
        else:
            self._schedule()

    def _read_next(self) -> RgbdFrame | None:
        frame = next(self._frames, None)
        if frame is None:
            self.skipped += len(self.reader.skipped)
            if self.loop and self.published:
                span = self.reader.entries[-1].stamp - self._first_stamp
                period = span / max(len(self.reader.entries) - 1, 1)
                self._lap_offset += span + period
                self._frames = iter(self.reader)
                frame = next(self._frames, None)
        return frame

    def _recorded(self, frame: RgbdFrame) -> float:
        return frame.stamp - self._first_stamp + self._lap_offset

    def _schedule(self) -> None:
        if self._next is None:
            self.timer.cancel()
            self._finish()
            return
        self.timer.next_due = self._start_wall + self._recorded(self._next) / self.rate

    def _tick(self) -> None:
        if self._wait_for > 0:
            if self.pub_color.get_subscription_count() < self._wait_for:
                self.timer.next_due = time.monotonic() + 0.05
                return
            self._wait_for = 0                # matched both ways once settled
            self._settling = True
            self.timer.next_due = time.monotonic() + DISCOVERY_SETTLE_S
            return
        if self._settling:                    # the recording starts now
            self._settling = False
            self._start_wall, self._start_ros = time.monotonic(), time.time()
            self._schedule()
            return
        frame = self._next
        if frame is None:
            return
        stamp = self._start_ros + self._recorded(frame) / self.rate
        self.pub_color.publish(color_message(frame, stamp, self.frame_id, self.mono))
        if frame.depth is not None:
            self.pub_depth.publish(depth_message(frame, stamp, self.frame_id,
                                                 self.depth_encoding))
        self.pub_info.publish(camera_info_message(frame, stamp, self.frame_id))
        if frame.pose is not None:
            self.pub_pose.publish(pose_message(frame.pose, stamp, self.world_frame_id))
        self.published += 1
        now = time.monotonic()
        if now - self._last_progress >= PROGRESS_EVERY_S:
            self._last_progress = now
            self.node.get_logger().info(
                f"frame {frame.index + 1}/{len(self.reader)} ({self.published} published, "
                f"{self.skipped + len(self.reader.skipped)} skipped)")
        self._next = self._read_next()
        self._schedule()

    def _finish(self) -> None:
        self.finished = True
        elapsed = time.monotonic() - self._start_wall
        # the last frames may still be in flight: let reliable readers acknowledge them before
        # the process (and its participant) goes away
        for pub in (self.pub_color, self.pub_depth, self.pub_info, self.pub_pose):
            pub.wait_for_acknowledgments(2.0)
        self.node.get_logger().info(
            f"done: {self.published} frames published in {elapsed:.1f} s, {self.skipped} "
            f"skipped{' (' + ', '.join(self.reader.skipped) + ')' if self.reader.skipped else ''}")


def main(args: list[str] | None = None) -> int:
    node = node_runtime.start_node("sequence_player", PARAMETERS, args)
    sequence = node.get_parameter("sequence").value
    try:
        reader = open_sequence(sequence, node.get_parameter("start").value,
                               node.get_parameter("end").value)
        player = SequencePlayer(node, reader)
    except (SequenceError, ValueError) as exc:
        return node_runtime.fail(node, str(exc))
    node.get_logger().info(f"playing {len(reader)} frames of {reader.kind} sequence "
                           f"{reader.path} at {player.rate}x{' in a loop' if player.loop else ''}")
    node_runtime.run(node, until=lambda: player.finished)
    return 0


if __name__ == "__main__":
    sys.exit(main())
