"""REP 105 on the device: ``odom → camera`` never leaps when the map under the device is
corrected (a map update, a relocalisation, the end of a loss), ``map → odom`` takes the
correction, and their product is the tracker's ``map`` pose at every frame."""

from __future__ import annotations

import itertools

import numpy as np

from device_tracker.odometry_frame import OdometryFrame


def _walk(i: int) -> np.ndarray:
    """Frame ``i`` of a walk: 1 cm a frame along x, turning 0.2° a frame about z."""
    a = np.radians(0.2 * i)
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    pose[:3, 3] = 0.01 * i, 0.0, 1.5
    return pose


def _shifted(pose: np.ndarray, dx: float, dy: float) -> np.ndarray:
    out = pose.copy()
    out[:2, 3] += dx, dy
    return out


def _run(frames: list[tuple[np.ndarray, bool, int, bool]]
         ) -> tuple[OdometryFrame, list[np.ndarray], list[np.ndarray]]:
    frame, odom, map_from_odom = OdometryFrame(), [], []
    for pose, tracked, version, relocalised in frames:
        o, m = frame.update(pose, tracked, version, relocalised)
        np.testing.assert_allclose(m @ o, pose, atol=1e-9)   # map → odom → camera = map pose
        odom.append(o)
        map_from_odom.append(m)
    return frame, odom, map_from_odom


def _largest_step(odom: list[np.ndarray]) -> float:
    return max(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) for a, b in itertools.pairwise(odom))


def test_without_corrections_odom_is_the_map_pose() -> None:
    frame, odom, map_from_odom = _run([(_walk(i), True, 1, False) for i in range(100)])
    assert frame.corrections == 0
    np.testing.assert_allclose(odom[-1], _walk(99), atol=1e-9)
    np.testing.assert_allclose(map_from_odom[-1], np.eye(4), atol=1e-9)


def test_a_map_update_that_moves_the_device_moves_map_to_odom_not_odom() -> None:
    """At frame 50 the edge's corrected map puts the device 20 cm off where it was: its map
    pose leaps, its odom pose goes on by one frame's motion, and map → odom holds the 20 cm."""
    frames = [(_walk(i) if i < 50 else _shifted(_walk(i), 0.2, -0.1), True,
               1 if i < 50 else 2, False) for i in range(100)]
    frame, odom, map_from_odom = _run(frames)
    assert frame.corrections == 1
    assert _largest_step(odom) < 0.0101                       # 1 cm a frame, nothing more
    np.testing.assert_allclose(map_from_odom[-1][:2, 3], [0.2, -0.1], atol=1e-4)
    np.testing.assert_allclose(odom[-1], _walk(99), atol=1e-4)


def test_a_relocalisation_after_a_loss_is_a_correction_too() -> None:
    """Frames 30-39 untracked (the motion model's guesses run on), then the device is found
    again 0.5 m off its guess by relocalisation: one correction, no leap in odom."""
    frames = []
    for i in range(80):
        if i < 30:
            frames.append((_walk(i), True, 1, False))
        elif i < 40:
            frames.append((_walk(i), False, 1, False))
        else:
            frames.append((_shifted(_walk(i), 0.5, 0.0), True, 1, i == 40))
    frame, odom, map_from_odom = _run(frames)
    assert frame.corrections == 1
    assert _largest_step(odom) < 0.0101
    np.testing.assert_allclose(map_from_odom[-1][:2, 3], [0.5, 0.0], atol=1e-3)
    # the rotation of the odom pose stays a rotation over a long run
    rotation = odom[-1][:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
