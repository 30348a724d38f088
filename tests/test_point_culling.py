"""Map points later keyframes should see and never find leave the edge's map; points they find,
and points they look at from behind, stay."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.local_mapping import LocalMapping, LocalMappingConfig
from twinslam.slam.back_end.point_culling import PointCullingConfig, count_and_cull, facing

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])


def _pose(x: float) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = x
    return p


def _seen_from(pose: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixels, depths) of ``world`` points from a camera at ``pose``."""
    cw = np.linalg.inv(pose)
    cam = world @ cw[:3, :3].T + cw[:3, 3]
    return cam[:, :2] / cam[:, 2:] * 500 + [320, 240], cam[:, 2]


def _wall(n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    return (rng.uniform([-1.0, -0.8, 3.0], [1.0, 0.8, 3.5], (n, 3)),
            rng.integers(0, 256, (n, 32), dtype=np.uint8))


def _walk(culling: PointCullingConfig | None) -> tuple[KeyFrameMap, list[int], list[int]]:
    """A keyframe makes points of a wall from depth; four later keyframes look at the wall and
    find only the first half of them (the second half was never there: spurious depth
    readings, a second copy of the wall); (map, the first keyframe's found points, its
    unfound ones)."""
    world, descs = _wall()
    m = KeyFrameMap()
    mapping = LocalMapping(m, K, (480, 640), LocalMappingConfig(culling=culling))
    uv, z = _seen_from(_pose(0.0), world)
    mapping.integrate(0, _pose(0.0), uv, descs, z, np.zeros(len(world), np.uint64))
    made = sorted(m.keyframes[0].points)
    assert len(made) == len(world)
    real = np.arange(len(world)) < len(world) // 2
    for kf in range(1, 5):
        pose = _pose(0.05 * kf)
        uv, z = _seen_from(pose, world[real])
        ids = np.array(made, dtype=np.uint64)[real]          # the device associated them
        mapping.integrate(kf, pose, uv, descs[real], z, ids)
    return m, [p for p, r in zip(made, real, strict=True) if r], \
        [p for p, r in zip(made, real, strict=True) if not r]


def test_a_point_no_later_keyframe_finds_is_culled() -> None:
    m, found, unfound = _walk(PointCullingConfig())
    assert all(p in m.points for p in found)
    assert not any(p in m.points for p in unfound)
    assert not any(p in m.keyframes[0].points or p in m.keyframes[0].measurements
                   for p in unfound)
    assert all(m.points[p].visible == 5 and m.points[p].found == 5 for p in found)


def test_without_culling_every_point_stays() -> None:
    m, found, unfound = _walk(None)
    assert all(p in m.points for p in found + unfound)


def test_a_point_is_judged_only_after_enough_views() -> None:
    """Found in 1 of 3 views, under half (the ratio here), but fewer views than min_visible
    (4): it stays; the fourth view unfound: culled."""
    m = KeyFrameMap()
    m.add_keyframe(0, np.eye(4))
    p = m.add_point(np.array([0.0, 0.0, 3.0]), np.zeros(32, np.uint8))
    m.observe(0, p)
    config = PointCullingConfig(min_found_ratio=0.5, min_visible=4)
    assert count_and_cull(m, [], [p], config) == [] and m.points[p].visible == 2
    assert count_and_cull(m, [], [p], config) == []
    assert count_and_cull(m, [], [p], config) == [p] and p not in m.points


def test_a_point_found_in_a_quarter_of_its_views_stays() -> None:
    """ORB-SLAM's bound: a found ratio below 0.25 culls, 2 of 5 views does not."""
    m = KeyFrameMap()
    m.add_keyframe(0, np.eye(4))
    p = m.add_point(np.array([0.0, 0.0, 3.0]), np.zeros(32, np.uint8))
    m.observe(0, p)
    config = PointCullingConfig()
    for _ in range(2):
        count_and_cull(m, [], [p], config)
    count_and_cull(m, [p], [p], config)                     # found again: 2 of 4
    assert count_and_cull(m, [], [p], config) == [] and p in m.points      # 2 of 5
    for _ in range(3):
        count_and_cull(m, [], [p], config)                  # 2 of 8: a quarter
    assert p in m.points
    assert count_and_cull(m, [], [p], config) == [p]        # 2 of 9


def test_a_point_seen_from_behind_is_not_in_view() -> None:
    """Its observers looked along +z at it; a camera beyond it looking back is past 60°."""
    m = KeyFrameMap()
    m.add_keyframe(0, np.eye(4))
    p = m.add_point(np.array([0.0, 0.0, 3.0]), np.zeros(32, np.uint8))
    m.observe(0, p)
    ids = np.array([p])
    assert facing(m, ids, _pose(0.3), 60.0).tolist() == [True]
    behind = np.eye(4)
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])              # turned round, at z = 6
    behind[2, 3] = 6.0
    assert facing(m, ids, behind, 60.0).tolist() == [False]


def test_views_survive_the_checkpoint(tmp_path: Path) -> None:
    m, found, _ = _walk(PointCullingConfig())
    m.save(tmp_path / "map.npz")
    back, _ = KeyFrameMap.load(tmp_path / "map.npz")
    assert [(back.points[p].visible, back.points[p].found) for p in found] == \
        [(m.points[p].visible, m.points[p].found) for p in found]


def test_a_points_direction_is_the_mean_of_its_observers_rays() -> None:
    """Two keyframes saw a point from either side, 40° off its normal each way: their mean
    ray is along the normal, so a camera 50° off it past the first keyframe still faces the
    point (the second keyframe's own ray is 90° away) and one 70° off does not; another
    point in the same call, seen by the second keyframe alone, is judged by its ray."""
    m = KeyFrameMap()
    target = np.array([0.0, 0.0, 3.0])
    for k, angle in enumerate((-40.0, 40.0)):
        pose = np.eye(4)
        a = np.radians(angle)
        pose[:3, 3] = target - 3.0 * np.array([np.sin(a), 0.0, np.cos(a)])
        m.add_keyframe(k, pose)
    both = m.add_point(target, np.zeros(32, np.uint8))
    m.observe(0, both)
    m.observe(1, both)
    one = m.add_point(target + np.array([0.0, 0.1, 0.0]), np.zeros(32, np.uint8))
    m.observe(1, one)
    ids = np.array([both, one])

    def camera_off_normal(deg: float) -> np.ndarray:
        pose = np.eye(4)
        b = np.radians(deg)
        pose[:3, 3] = target - 3.0 * np.array([-np.sin(b), 0.0, np.cos(b)])
        return pose

    assert facing(m, ids, camera_off_normal(50.0), 60.0).tolist() == [True, False]
    assert facing(m, ids, camera_off_normal(70.0), 60.0).tolist() == [False, False]
    assert facing(m, ids[:1], camera_off_normal(0.0), 60.0).tolist() == [True]


def test_a_keyframes_views_are_counted_for_every_point_at_once() -> None:
    """The points it found gain a view and a find, the others its view held a view; of
    those, the ones whose found ratio fell below the bound leave the map, in id order, and
    a point that left already is passed over."""
    m = KeyFrameMap()
    m.add_keyframe(0, np.eye(4))
    ids = []
    for j in range(12):
        p = m.add_point(np.array([0.0, 0.0, 2.0 + j]), np.zeros(32, np.uint8))
        m.observe(0, p)
        m.points[p].visible, m.points[p].found = 3 + j % 3, 1 + j % 2
        ids.append(p)
    before = {p: (m.points[p].visible, m.points[p].found) for p in ids}
    found, held = ids[:4], ids[4:]
    m.remove_point(held[-1])
    culled = count_and_cull(m, set(found), [*held, *found], PointCullingConfig())
    expected = []
    for p in ids[:-1]:
        visible, found_n = before[p]
        visible, found_n = (visible + 1, found_n + 1) if p in found else (visible + 1, found_n)
        if p not in found and visible >= 4 and found_n < 0.25 * visible:
            expected.append(p)
        else:
            assert (m.points[p].visible, m.points[p].found) == (visible, found_n)
    assert culled == sorted(expected) and expected
    assert not any(p in m.points for p in culled)
