"""ROS 2 launch file (``ros2 launch twinslam twinslam_launch.py``) for hosts with ROS 2: the
same nodes and parameter file as ``twinslam launch`` (which needs no ROS).

    ros2 launch twinslam twinslam_launch.py sequence:=/data/7scenes twin:=true
    ros2 launch twinslam twinslam_launch.py \\
        params_file:=$(ros2 pkg prefix twinslam)/share/twinslam/config/paper-table1.yaml

On separate machines, ``host:=device`` (camera player + device tracker), ``host:=edge`` or
``host:=twin`` starts that machine's share, with the same ``ROS_DOMAIN_ID`` everywhere:

    ros2 launch twinslam twinslam_launch.py host:=edge policy:=adapt

``every:=2 phase:=1`` plays one frame in two (those numbered 1 modulo 2), as a camera at half
the recorded rate: the device is told its slot in the frames it sees (the parameter file's
``slot_frames`` and ``frame_rate_hz`` divided by ``every``; a slot that does not split so is
refused before any node starts) — two pairs at phases 0 and 1 never show one image.
``rate:=2`` plays the frames twice as fast, and the device's ``frame_rate_hz`` is doubled with
it: its slots are cut by frame stamps, so it still closes one a ``slot_frames`` of them.

``namespace:=/ar1`` puts a device/edge pair under ``/ar1`` (a second pair under ``/ar2`` shares
the domain); ``/tf`` is shared by every pair, so give each its own frames as well:
``map_frame:=ar1/map camera_frame:=ar1/camera odom_frame:=ar1/odom``. The bundled parameter
files key each section ``/**/NODE`` so that it reaches its node in any namespace; a file of your
own keyed by plain node names reaches only nodes in the root namespace (each node warns of a
section it cannot read). The nodes run with the
package's Fast DDS profile (``config/fastdds.xml``) unless ``FASTRTPS_DEFAULT_PROFILES_FILE``
names another.

Needs the ROS 2 ``launch`` / ``launch_ros`` packages (never PyPI's unrelated ``launch``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.launch_context import LaunchContext
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription
from twinslam.live.parameter_files import node_parameters
from twinslam.sequence_player.playback import played_device_slot


def device_slot(context: LaunchContext) -> dict[str, Any]:
    """The device's parameters that follow the player's ``every`` and ``rate``: none at every
    frame at the recorded speed; else its slot's frames and nominal frame rate as the
    parameter file gives them, the rate × ``rate`` (slots are cut by frame stamps) and both
    divided by ``every`` — what ``twinslam launch --every/--rate`` tells its devices."""
    given = LaunchConfiguration("every").perform(context)
    try:
        every = int(given)
    except ValueError:
        every = 0
    if every < 1:
        raise RuntimeError(f"every:={given}: not a whole number of 1 or more (1 plays every "
                           "frame)")
    given_rate = LaunchConfiguration("rate").perform(context)
    try:
        rate = float(given_rate)
    except ValueError:
        rate = float("nan")
    if every == 1 and rate == 1.0:
        return {}
    section = node_parameters(Path(LaunchConfiguration("params_file").perform(context)),
                              "device_tracker")
    try:
        slot_frames, frame_rate = played_device_slot(section, every, rate)
    except ValueError as err:
        if not (rate > 0 and math.isfinite(rate)):
            raise RuntimeError(f"rate:={given_rate}: {err}") from None
        raise RuntimeError(f"every:={every}: {err} (the parameter file's device_tracker "
                           "slot_frames must be a multiple of it)") from None
    return {"slot_frames": slot_frames, "frame_rate_hz": frame_rate}


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("twinslam")
    params = os.path.join(share, "config", "twinslam.yaml")
    profile = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE",
                             os.path.join(share, "config", "fastdds.xml"))
    arg = LaunchConfiguration

    def on(*hosts: str, given: str = "", empty: str = "") -> IfCondition:
        """Start the node when this machine is one of ``hosts`` (or runs them all) — and, for
        the two variants of a node, when the launch argument ``given`` was given a value or
        ``empty`` was left empty (the parameter file's value then stands)."""
        test = ["'", arg("host"), f"' in {('all', *hosts)!r}"]
        if given:
            test += [" and '", arg(given), "' != ''"]
        if empty:
            test += [" and '", arg(empty), "' == ''"]
        return IfCondition(PythonExpression(test))

    def devices(context: LaunchContext) -> list[Node]:
        """The device tracker, in its two variants (``map_source`` given or left to the
        parameter file), told its slot in the frames its camera plays."""
        slot = device_slot(context)
        return [
            Node(package="twinslam", executable="device_tracker", name="device_tracker",
                 namespace=arg("namespace"),
                 parameters=[arg("params_file"), {"map_frame": arg("map_frame"),
                                                   "camera_frame": arg("camera_frame"),
                                                   "odom_frame": arg("odom_frame"),
                                                   "map_source": arg("map_source")}, slot],
                 output="screen", condition=on("device", given="map_source")),
            Node(package="twinslam", executable="device_tracker", name="device_tracker",
                 namespace=arg("namespace"),
                 parameters=[arg("params_file"), {"map_frame": arg("map_frame"),
                                                   "camera_frame": arg("camera_frame"),
                                                   "odom_frame": arg("odom_frame")}, slot],
                 output="screen", condition=on("device", empty="map_source")),
        ]

    return LaunchDescription([
        SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", profile),
        DeclareLaunchArgument("params_file", default_value=params,
                              description="ROS 2 parameter file of every node: the default "
                              "device (config/twinslam.yaml) or the paper's Table I device "
                              "(config/paper-table1.yaml, in the same share folder)"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="namespace of this device/edge pair, e.g. /ar1"),
        DeclareLaunchArgument("map_frame", default_value="map",
                              description="the pair's map frame on /tf (e.g. ar1/map)"),
        DeclareLaunchArgument("camera_frame", default_value="camera",
                              description="the pair's camera frame on /tf (e.g. ar1/camera)"),
        DeclareLaunchArgument("odom_frame", default_value="odom",
                              description="the pair's REP 105 odom frame on /tf, between map "
                              "and camera (e.g. ar1/odom)"),
        DeclareLaunchArgument("sequence", default_value="synthetic",
                              description="SUN3D / 7-Scenes / TUM RGB-D folder, a bag of "
                              "twinslam record, or synthetic[:frames]"),
        DeclareLaunchArgument("policy", default_value="",
                              description="the edge's map management: lff | pu | adapt | "
                              "random | mbrl | mpc; empty: the parameter file's (lff in "
                              "twinslam.yaml, adapt in paper-table1.yaml)"),
        DeclareLaunchArgument("map_source", default_value="",
                              description="where the device's poses come from: edge+local "
                              "(the edge's map and its own recent points) | edge (only the "
                              "edge's map, the paper's device); empty: the parameter file's"),
        DeclareLaunchArgument("start", default_value="0",
                              description="the sequence's first frame played"),
        DeclareLaunchArgument("end", default_value="-1",
                              description="the first frame not played; -1: to the end"),
        DeclareLaunchArgument("loop", default_value="false",
                              description="play the sequence again from start at its end"),
        DeclareLaunchArgument("rate", default_value="1.0",
                              description="playback speed, x the recorded frame rate "
                              "(the device's frame_rate_hz from the parameter file is "
                              "multiplied by it: a slot stays slot_frames frames)"),
        DeclareLaunchArgument("every", default_value="1",
                              description="play one frame in every this many, each at its "
                              "time in the walk (a camera at 1/every of the recorded rate); "
                              "the device's slot_frames and frame_rate_hz from the parameter "
                              "file are divided by it, so a slot lasts as long"),
        DeclareLaunchArgument("phase", default_value="0",
                              description="which frames every plays: those numbered phase "
                              "modulo every, 0 to every - 1 (two pairs at every:=2, phases 0 "
                              "and 1, never show one image)"),
        DeclareLaunchArgument("twin", default_value="false",
                              description="start udt_node, the user digital twin, too"),
        DeclareLaunchArgument(
            "wait_for_subscribers", default_value="1",
            description="the player holds its first frame until this many readers of the "
            "camera match (the device's): nodes start in any order — an edge and device that "
            "take 30 s to start on a busy machine still see every frame; 0: play at once"),
        DeclareLaunchArgument("host", default_value="all",
                              description="all | device | edge | twin: this machine's nodes"),
        # each of edge and device in two variants: with the launch argument that overrides the
        # parameter file where it was given, without it where it was left empty; the devices
        # first, whose slot is checked against every before any node starts
        OpaqueFunction(function=devices),
        Node(package="twinslam", executable="edge_mapper", name="edge_mapper",
             namespace=arg("namespace"),
             parameters=[arg("params_file"), {"policy": arg("policy"),
                                               "map_frame": arg("map_frame")}],
             output="screen", condition=on("edge", given="policy")),
        Node(package="twinslam", executable="edge_mapper", name="edge_mapper",
             namespace=arg("namespace"),
             parameters=[arg("params_file"), {"map_frame": arg("map_frame")}],
             output="screen", condition=on("edge", empty="policy")),
        Node(package="twinslam", executable="udt_node", name="udt_node", namespace=arg("namespace"),
             parameters=[arg("params_file")], output="screen",
             condition=IfCondition(PythonExpression([
                 "'", arg("host"), "' == 'twin' or ('", arg("host"), "' == 'all' and '",
                 arg("twin"), "'.lower() == 'true')"]))),
        Node(package="twinslam", executable="sequence_player", name="sequence_player",
             namespace=arg("namespace"),
             parameters=[arg("params_file"), {"sequence": arg("sequence"),
                                               # rate:=2 reads as an integer, which
                                               # the player's double refuses
                                               "rate": ParameterValue(arg("rate"),
                                                                      value_type=float),
                                               "start": arg("start"),
                                               "end": arg("end"),
                                               "loop": arg("loop"),
                                               "every": arg("every"),
                                               "phase": arg("phase"),
                                               "map_frame": arg("map_frame"),
                                               "frame_id": arg("camera_frame"),
                                               "wait_for_subscribers":
                                                   arg("wait_for_subscribers")}],
             output="screen",
             condition=on("device")),
    ])
