"""The player node's ROS parameters: name, default, description, range and checks."""

from __future__ import annotations

import re

from msg_schemas import qos, topics
from twinslam.node_runtime.parameters import ParamSpec
from twinslam.sequence_player.messages import DEPTH_ENCODINGS
from twinslam.sequence_player.playback import ORDERS, parse_bursts
from twinslam.sequences.opening import AUTO


def _bursts_error(value: object) -> str | None:
    try:
        parse_bursts(str(value))
    except ValueError as exc:
        return str(exc)
    return None


def _group_error(value: object) -> str | None:
    if value == "" or re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", str(value)):
        return None
    return "a group is a topic name's token: a letter, then letters, digits, underscores"


PARAMETERS = (
    ParamSpec("sequence", "synthetic", "dataset folder, rosbag2 (MCAP) of `twinslam record`, "
              "or synthetic[:frames] (the room) / synthetic-corridor[:frames]"),
    ParamSpec("rate", 1.0, "playback speed, x the recorded frame rate", low=1e-3, high=1e3),
    ParamSpec("loop", False, "start over at the end"),
    ParamSpec("start", 0, "first frame played", low=0),
    ParamSpec("end", -1, "first frame not played; -1: to the end", low=-1),
    ParamSpec("stop_after", 0, "end the playback once this many frames are published (0: "
              "no limit); live: `ros2 param set` ends a long or looping playback where one "
              "chooses (a slot's end); a count already passed is refused", low=0, live=True),
    ParamSpec("colour_intrinsics", AUTO, "the camera a dataset folder is seen through: auto "
              "(a 7-Scenes folder, whose intrinsics file is its depth camera's, through its "
              "colour camera, 525 px, each depth image registered to it; any other source as "
              "it is), a 3×3 intrinsics file of the colour camera, or empty: the folder's own"),
    ParamSpec("depth_encoding", "16UC1", "16UC1 (millimetres) or 32FC1 (metres)",
              check=lambda v: None if v in DEPTH_ENCODINGS
              else f"must be one of {', '.join(DEPTH_ENCODINGS)}"),
    ParamSpec("mono", False, "mono8 colour instead of rgb8"),
    ParamSpec("frame_id", "camera", "frame id of the camera topics"),
    ParamSpec("world_frame_id", "world", "frame id of the ground-truth poses"),
    ParamSpec("map_frame", "map", "the device's map frame, put in world_frame_id on "
              "/tf_static at the first played frame's ground truth (a device's map frame is its "
              "first frame's camera frame); empty: no static transform"),
    ParamSpec("path_window", 900, "poses camera/ground_truth_path holds: the newest ones "
              "(900: 30 s at 30 Hz, as device/path), published once a second", low=1,
              high=10_000_000),
    ParamSpec("wait_for_subscribers", 0, "hold the first frame until this many colour "
              "subscribers match", low=0),
    ParamSpec("pace_frames", 0, "at most this many published frames left for the device "
              "(device/pose in this namespace) to pose: the next frame waits while that many "
              "are, the recording's clock stopped meanwhile, so a device slower than its camera "
              f"sees every frame instead of dropping them past its camera backlog "
              f"({qos.CAMERA.depth}); 0: real time",
              low=0, high=qos.CAMERA.depth - 1),
    ParamSpec("pace_group", "", "paced cameras that keep one recording clock (a fleet's): "
              "each holds as long as the one of the group that held longest, so every camera "
              "of it waits while any device is behind and the walks meet when the recording "
              f"has them meet ({topics.PLAYBACK_PACE}/GROUP); empty: this camera alone; "
              "letters, digits and underscores, needs pace_frames", check=_group_error),
    ParamSpec("start_delay_s", 0.0, "seconds the first frame waits (after the subscribers "
              "matched): a device that comes to the place later than the others", low=0.0,
              high=86_400.0),
    ParamSpec("order", "forward", "forward; forward_backward: every place visited twice; "
              "backward: from the last frame to the first, a second device walking towards "
              "the first; backward_forward: back to the first frame and on to the last again "
              "(all but forward: dataset folders and synthetic only)",
              check=lambda v: None if v in ORDERS else f"must be one of {', '.join(ORDERS)}"),
    ParamSpec("blank", "", "bursts of the walk's frames (the order's positions, whichever "
              "every and phase play) shown black with no depth (a covered lens): "
              "START:COUNT[,START:COUNT...]; empty: none", check=_bursts_error),
    ParamSpec("every", 1, "play one frame in every this many, each at its time in the walk: "
              "a camera at 1/every of the recorded rate (tell the device: its frame_rate_hz "
              "and slot_frames divided alike)", low=1, high=1000),
    ParamSpec("phase", 0, "which frames every plays: the sequence's frames numbered phase "
              "modulo every (from start), 0 to every - 1: at every:=2, a device at phase 0 "
              "and one at phase 1 never show one image, whichever ways they walk",
              low=0, high=999),
)
