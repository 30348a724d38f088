"""The TF tree's messages: tf2_msgs as `make` builds it from msg_schemas/standard (no wheel
carries it) is the standard Jazzy type a ROS host's viewers read, and the transforms the device
and the player broadcast are the poses they stand for."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from msg_schemas.headers import stamp_seconds
from msg_schemas.transforms import tf_message, transform_matrix, transform_stamped


@pytest.mark.parametrize("name", ["TFMessage", "TF2Error"])
def test_the_built_tf2_msgs_has_the_standard_type_hash(name: str) -> None:
    """DDS matches by type name and Jazzy announces each type's RIHS01 hash: the hash of the
    package built here equals the one rosbags' own copy of Jazzy's interfaces gives, so RViz or
    Foxglove on a ROS host take our /tf as theirs."""
    from rosbags.typesys import Stores, get_typestore

    # make installs into the venv's prefix, an ament prefix like /opt/ros/jazzy
    described = Path(sys.prefix) / "share" / "tf2_msgs" / "msg" / f"{name}.json"
    ours = json.loads(described.read_text(encoding="utf-8"))["type_hashes"][0]
    standard = get_typestore(Stores.ROS2_JAZZY).hash_rihs01(f"tf2_msgs/msg/{name}")
    assert ours == {"type_name": f"tf2_msgs/msg/{name}", "hash_string": standard}


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1),
    st.lists(st.floats(-50, 50), min_size=3, max_size=3), st.floats(0, 2e9))
def test_a_transform_carries_its_pose_and_stamp(quat: list[float], xyz: list[float],
                                                stamp: float) -> None:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(quat).as_matrix()
    pose[:3, 3] = xyz
    msg = transform_stamped(pose, stamp, "map", "camera")
    assert (msg.header.frame_id, msg.child_frame_id) == ("map", "camera")
    assert stamp_seconds(msg.header) == pytest.approx(stamp, abs=1e-9 * max(1.0, stamp))
    np.testing.assert_allclose(transform_matrix(msg), pose, atol=1e-9)


def test_a_transform_serialises_as_one_tf_sample() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from tf2_msgs.msg import TFMessage

    moved = np.eye(4)
    moved[:3, 3] = [1.0, 2.0, 3.0]
    sample = tf_message(transform_stamped(moved, 12.5, "world", "map"),
                        transform_stamped(np.eye(4), 12.5, "map", "camera"))
    back = deserialize_message(serialize_message(sample), TFMessage)
    assert [(t.header.frame_id, t.child_frame_id) for t in back.transforms] == [
        ("world", "map"), ("map", "camera")]
    np.testing.assert_allclose(transform_matrix(back.transforms[0]), moved)


@pytest.mark.parametrize("parent, child", [("map", "map"), ("", "camera"), ("map", "")])
def test_a_transform_needs_two_named_frames(parent: str, child: str) -> None:
    with pytest.raises(ValueError, match="frame"):
        transform_stamped(np.eye(4), 0.0, parent, child)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 1e-3), st.floats(1e-9, 1e-4))
def test_rotations_convert_as_scipy_converts_them_even_slightly_off_orthonormal(
        quat: list[float], noise: float) -> None:
    """The nodes' NumPy conversions (twinslam.rotations) against SciPy's ``Rotation``:
    the same matrix of a quaternion and the same quaternion of a matrix, sign included, also for
    a matrix a dataset stored in float32 and a little off orthonormal."""
    from twinslam.rotations import (
        matrix_from_quaternion,
        matrix_from_yaw_pitch_roll,
        quaternion_from_matrix,
    )

    rotation = Rotation.from_quat(quat)
    np.testing.assert_allclose(matrix_from_quaternion(quat), rotation.as_matrix(), atol=1e-12)
    off = rotation.as_matrix() + noise * np.sin(np.arange(9.0)).reshape(3, 3)
    np.testing.assert_allclose(quaternion_from_matrix(off), Rotation.from_matrix(off).as_quat(),
                               atol=1e-9)
    yaw, pitch, roll = (float(v) for v in 3 * np.asarray(quat[:3]))
    np.testing.assert_allclose(matrix_from_yaw_pitch_roll(yaw, pitch, roll),
                               Rotation.from_euler("yxz", [yaw, pitch, roll]).as_matrix(),
                               atol=1e-12)
    with pytest.raises(ValueError, match="not a rotation quaternion"):
        matrix_from_quaternion([0.0, 0.0, 0.0, 0.0])


def test_a_stack_of_rotations_converts_as_each_one_alone() -> None:
    """The map update converts every keyframe's pose at once: each row of the batch is the
    quaternion SciPy gives that matrix, whichever of Markley's four formulas it takes (the
    trace, or the largest diagonal entry, 180° turns included), and the messages carry them."""
    from msg_schemas.poses import pose_matrix, pose_msgs
    from twinslam.rotations import quaternion_from_matrix, quaternions_from_matrices

    turns = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]),
             np.diag([-1.0, -1.0, 1.0])]
    rotations = np.concatenate([np.stack(turns),
                                Rotation.random(60, random_state=3).as_matrix()])
    batch = quaternions_from_matrices(rotations)
    picks = {int(np.argmax([*np.diagonal(r), np.trace(r)])) for r in rotations}
    assert picks == {0, 1, 2, 3}
    for r, q in zip(rotations, batch, strict=True):
        np.testing.assert_allclose(q, quaternion_from_matrix(r), atol=1e-15)
        np.testing.assert_allclose(q, Rotation.from_matrix(r).as_quat(), atol=1e-12)
    poses = np.tile(np.eye(4), (len(rotations), 1, 1))
    poses[:, :3, :3] = rotations
    poses[:, :3, 3] = np.arange(3 * len(rotations)).reshape(-1, 3)
    for pose, msg in zip(poses, pose_msgs(poses), strict=True):
        np.testing.assert_allclose(pose_matrix(msg), pose, atol=1e-12)
    assert pose_msgs(np.zeros((0, 4, 4))) == []
