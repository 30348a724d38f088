"""A loop's corrections carried into the map: each moved keyframe by its own, each point with
its reference keyframe (its oldest observer), a point whose reference did not move — or that
no keyframe observes — where it was."""

from __future__ import annotations

import numpy as np

from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.loop_correction import move_keyframes


def _shift(x: float, turn_deg: float) -> np.ndarray:
    a = np.radians(turn_deg)
    c = np.eye(4)
    c[:3, :3] = [[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
    c[0, 3] = x
    return c


def test_points_move_with_their_oldest_observer() -> None:
    m = KeyFrameMap()
    for k in (10, 20, 30):
        m.add_keyframe(k, np.eye(4))
    seen_by = {(10,): [1.0, 0.0, 2.0], (20, 30): [0.0, 1.0, 2.0], (30,): [1.0, 1.0, 3.0],
               (10, 30): [2.0, 0.0, 1.0], (): [5.0, 5.0, 5.0]}
    ids = {}
    for observers, xyz in seen_by.items():
        pid = m.add_point(np.array(xyz), np.zeros(32, np.uint8))
        for k in observers:
            m.observe(k, pid, (320.0, 240.0), 2.0)
        ids[observers] = pid
    moves = {20: _shift(0.3, 10.0), 30: _shift(-0.2, -5.0)}
    move_keyframes(m, moves)
    np.testing.assert_allclose(m.keyframes[20].pose, moves[20])
    np.testing.assert_allclose(m.keyframes[10].pose, np.eye(4))
    for observers, xyz in seen_by.items():
        c = moves.get(min(observers, default=-1), np.eye(4))
        expected = c[:3, :3] @ np.array(xyz) + c[:3, 3]
        np.testing.assert_allclose(m.points[ids[observers]].position, expected, atol=1e-12)
