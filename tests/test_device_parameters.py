"""The device's ``map_source`` as a ROS 2 user meets it: an unknown value stops the node at start
with the reason (exit 2), and through the standard parameter service an unknown value is
refused with the reason while a known one is taken live."""

from __future__ import annotations

import subprocess
import sys

import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, SetParameters

from tests.test_edge_parameters import _call
from twinslam.hosts.fastdds import REPO_ROOT
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession


def _set_map_source(ros: RosSession, value: str) -> object:
    request = SetParameters.Request(parameters=[Parameter(
        name="map_source", value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                string_value=value))])
    return _call(ros, SetParameters, "/device_tracker/set_parameters", request).results[0]


def test_an_unknown_map_source_is_refused_at_start_and_when_set(domain: LoopbackDomain,
                                                               ros: RosSession) -> None:
    done = subprocess.run([sys.executable, "-m", "device_tracker.node", "--ros-args", "-p",
                           "map_source:=local"], env=domain.env_for(None), cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "unknown map source 'local'" in done.stderr and "Traceback" not in done.stderr

    device = domain.spawn(["-m", "device_tracker.node"])
    described = _call(ros, DescribeParameters, "/device_tracker/describe_parameters",
                      DescribeParameters.Request(names=["map_source"])).descriptors[0]
    assert not described.read_only and "paper" in described.description
    refused = _set_map_source(ros, "cloud")
    assert not refused.successful and "unknown map source 'cloud'" in refused.reason
    assert _set_map_source(ros, "edge").successful
    code, _out, err = domain.stop(device)
    assert code == 0 and "Traceback" not in err, err[-2000:]


def test_a_camera_frame_equal_to_the_map_frame_is_refused_with_the_reason() -> None:
    """The pose on /tf goes from map_frame to camera_frame: one frame for both is no
    transform, so the settings (and the node's start, exit 2 as above) refuse it."""
    from device_tracker.parameters import PARAMETERS, DeviceSettings

    values = {spec.name: spec.default for spec in PARAMETERS}
    assert DeviceSettings.from_parameters(values).camera_frame == ""   # the images' frame id
    with pytest.raises(ValueError, match="camera_frame and map_frame are both 'map'"):
        DeviceSettings.from_parameters(dict(values, camera_frame="map"))


def test_the_pose_gate_is_set_by_parameters() -> None:
    """``reloc_min_inliers`` and ``reloc_probation_frames`` reach the tracker (a user loosens
    or tightens the gate for a camera of their own, or measures without it)."""
    from device_tracker.parameters import PARAMETERS, DeviceSettings

    values = {spec.name: spec.default for spec in PARAMETERS}
    tracking = DeviceSettings.from_parameters(
        dict(values, reloc_min_inliers=50, reloc_probation_frames=0)).tracking
    assert (tracking.reloc_min_inliers, tracking.reloc_probation_frames) == (50, 0)
    assert tracking.relocalise


def test_relocalisation_at_the_edge_is_asked_for_by_a_parameter_on_each_side() -> None:
    """Off by default on both sides (measured to lose more frames); ``reloc_period_s`` on the
    device and ``reloc_restore_keyframes`` on the edge turn it on."""
    from device_tracker.parameters import PARAMETERS as DEVICE
    from device_tracker.parameters import DeviceSettings
    from edge_mapper.parameters import PARAMETERS as EDGE
    from edge_mapper.parameters import edge_config

    device = {spec.name: spec.default for spec in DEVICE}
    edge = {spec.name: spec.default for spec in EDGE}
    assert DeviceSettings.from_parameters(device).reloc_period_s == 0.0
    assert edge_config(edge).reloc_restore_keyframes == 0
    assert DeviceSettings.from_parameters(dict(device, reloc_period_s=0.5)).reloc_period_s == 0.5
    assert edge_config(dict(edge, reloc_restore_keyframes=3)).reloc_restore_keyframes == 3


def test_a_lost_device_tracks_with_its_own_points_after_the_seconds_a_parameter_says() -> None:
    """``own_map_after_s`` is seconds of frame stamps: at 30 Hz the default 0.1 s is the third
    lost frame, at 60 Hz the sixth; 0 is the paper's device, which waits for the edge's map."""
    from device_tracker.parameters import PARAMETERS, DeviceSettings

    values = {spec.name: spec.default for spec in PARAMETERS}
    assert DeviceSettings.from_parameters(dict(values, frame_rate_hz=30.0)).own_map_after == 3
    assert DeviceSettings.from_parameters(dict(values, frame_rate_hz=60.0)).own_map_after == 6
    assert DeviceSettings.from_parameters(dict(values, own_map_after_s=0.0)).own_map_after == 0
