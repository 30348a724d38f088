"""Where a map point was seen from: the mean ray of the keyframes that observed it, the test
that a camera sees it from within an angle of that, and the local map carrying it through a
renumbering and a frame correction."""

from __future__ import annotations

import numpy as np

from twinslam.slam.front_end.local_map import LocalMap
from twinslam.slam.viewing_directions import (
    mean_viewing_directions,
    rays_from,
    seen_from_afar,
)


def _at(x: float, y: float, z: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = (x, y, z)
    return pose


def test_a_points_direction_is_the_mean_ray_of_the_keyframes_that_observed_it() -> None:
    ids = np.array([30, 10, 20], dtype=np.uint64)
    positions = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [5.0, 5.0, 5.0]])
    poses = np.stack([_at(-1, 0, 0), _at(1, 0, 0)])
    # point 30 seen by both, point 10 by the first only, point 20 by none; 99 is not held
    seen = [np.array([30, 10, 99], dtype=np.uint64), np.array([30], dtype=np.uint64)]
    views = mean_viewing_directions(ids, positions, poses, seen)
    np.testing.assert_allclose(views[0], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(views[1], np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0))
    assert np.isnan(views[2]).all()
    assert np.isnan(mean_viewing_directions(ids, positions, poses[:0], [])).all()


def test_a_camera_sees_a_point_from_afar_past_the_angle_and_never_without_a_direction(
        ) -> None:
    point = np.array([[0.0, 0.0, 0.0]] * 3)
    views = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [np.nan] * 3])
    for degrees, afar in ((59.0, False), (61.0, True), (180.0, True)):
        a = np.radians(degrees)
        centre = -np.array([np.sin(a), 0.0, np.cos(a)])     # its ray turned by `degrees`
        got = seen_from_afar(views, point, centre, 60.0)
        assert got.tolist() == [afar, afar, False], degrees
    assert not seen_from_afar(views, point, np.array([0.0, 0.0, 1.0]), 180.0).any()


def test_the_local_map_keeps_each_points_direction_when_renumbered_and_moved() -> None:
    points = LocalMap(2)
    world = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 2.0]])
    points.add(world[:1], np.zeros((1, 32), np.uint8), 0)
    points.add(world[1:], np.zeros((2, 32), np.uint8), 1, views=rays_from(np.zeros(3),
                                                                          world[1:]))
    assert np.isnan(points.views[0]).all()
    kept = points.take(np.array([0, 2]))
    assert np.isnan(kept.views[0]).all()
    np.testing.assert_allclose(kept.views[1], world[2] / np.linalg.norm(world[2]))
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]   # 90° about z
    turn[:3, 3] = (3.0, 0.0, 0.0)
    kept.move(turn)
    np.testing.assert_allclose(kept.views[1], turn[:3, :3] @ world[2] / np.linalg.norm(world[2]))
    np.testing.assert_allclose(np.linalg.norm(kept.views[1]), 1.0)
