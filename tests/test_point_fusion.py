"""A keyframe restored from the archive brings back the points it saw; where the map made
those points again since, the two copies are fused into the map's, and a look-alike corner
elsewhere along the ray stays a point of its own."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, restore_into
from twinslam.slam.back_end.keyframe_map import KeyFrameMap, MapError
from twinslam.slam.back_end.point_fusion import fuse_restored
from twinslam.slam.camera import Camera

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
CAMERA = Camera(K, (480, 640))


def _seen_from(pose: np.ndarray, world: np.ndarray) -> np.ndarray:
    """(u, v, depth) of ``world`` points from a camera at ``pose`` (camera-to-map)."""
    cw = np.linalg.inv(pose)
    cam = world @ cw[:3, :3].T + cw[:3, 3]
    uv = cam[:, :2] / cam[:, 2:] @ K[:2, :2].T + K[:2, 2]
    return np.column_stack([uv, cam[:, 2]])


def _world(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    return (rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 5.0], (n, 3)),
            rng.integers(0, 256, (n, 32), dtype=np.uint8))


def _observed(m: KeyFrameMap, kf: int, pose: np.ndarray, pids: list[int]) -> None:
    uvd = _seen_from(pose, np.array([m.points[p].position for p in pids]))
    m.observe_many(kf, pids, uvd[:, :2].tolist(), uvd[:, 2].tolist())


def test_a_restored_keyframes_points_made_again_since_are_fused_into_the_maps() -> None:
    """Keyframe 1 saw 60 corners and left for the archive with its points; keyframe 2 saw
    the same place later and the map made 40 of those corners anew (2 cm off: a new depth
    reading). Restoring keyframe 1 fuses those 40 into keyframe 2's points; the 20 corners
    only keyframe 1 saw come back as they were."""
    rng = np.random.default_rng(0)
    world, desc = _world(rng, 60)
    pose = np.eye(4)
    m = KeyFrameMap()
    m.add_keyframe(1, pose)
    old = [m.add_point(x, d) for x, d in zip(world, desc, strict=True)]
    _observed(m, 1, pose, old)
    archived = ArchivedKeyFrame.of(m, 1, slot=0)
    m.evict(1)
    assert not m.points
    later = pose.copy()
    later[0, 3] = 0.1
    m.add_keyframe(2, later)
    shift = np.array([0.02, 0.0, 0.0])
    new = [m.add_point(x + shift, d) for x, d in zip(world[:40], desc[:40], strict=True)]
    _observed(m, 2, later, new)
    returned = restore_into(m, archived)
    assert sorted(returned) == sorted(old) and len(m.points) == 100
    fused = fuse_restored(m, 1, returned, CAMERA)
    assert fused == dict(zip(old[:40], new, strict=True))
    assert len(m.points) == 60
    assert m.keyframes[1].points == set(new) | set(old[40:])
    # the two keyframes now share the 40 corners both see: the covisibility counts them
    assert m.covisibility([1, 2])[0, 1] == 40
    # keyframe 1 observes each fused point where it saw its own copy
    np.testing.assert_allclose(m.keyframes[1].measurements[new[0]][:2],
                               archived.measurements[0, :2])


def test_a_look_alike_along_the_ray_is_no_duplicate() -> None:
    """A point with the same descriptor and pixel, but a metre deeper, is another corner."""
    rng = np.random.default_rng(1)
    world, desc = _world(rng, 30)
    m = KeyFrameMap()
    m.add_keyframe(1, np.eye(4))
    old = [m.add_point(x, d) for x, d in zip(world, desc, strict=True)]
    _observed(m, 1, np.eye(4), old)
    archived = ArchivedKeyFrame.of(m, 1, slot=0)
    m.evict(1)
    m.add_keyframe(2, np.eye(4))
    deeper = [m.add_point(x * 1.25, d) for x, d in zip(world, desc, strict=True)]   # same pixel
    _observed(m, 2, np.eye(4), deeper)
    assert fuse_restored(m, 1, restore_into(m, archived), CAMERA) == {}
    assert len(m.points) == 60


def test_fusing_a_point_into_itself_or_an_unknown_one_is_refused() -> None:
    m = KeyFrameMap()
    p = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
    with pytest.raises(MapError, match="cannot fuse"):
        m.fuse(p, p)
    with pytest.raises(MapError, match="cannot fuse"):
        m.fuse(p, 99)


def _fusable() -> tuple[KeyFrameMap, list[tuple[int, int]]]:
    """Keyframes 1 and 2 observe points of their own; each of 2's first four is a duplicate of
    one of 1's (keep, drop) — and keyframe 3 sees a kept point and its duplicate both."""
    m = KeyFrameMap()
    for k in (1, 2, 3):
        m.add_keyframe(k, np.eye(4))
    rng = np.random.default_rng(4)
    own = {k: [m.add_point(rng.normal(size=3), rng.integers(0, 256, 32, dtype=np.uint8))
               for _ in range(6)] for k in (1, 2)}
    for k, pids in own.items():
        for p in pids:
            m.observe(k, p, (float(p), float(k)), 2.0)
    m.observe(3, own[1][0], (5.0, 5.0), 1.0)
    m.observe(3, own[2][0], (6.0, 6.0), 1.0)
    return m, list(zip(own[1][:4], own[2][:4], strict=True))


def test_points_fused_at_once_are_as_points_fused_one_by_one() -> None:
    """A restored keyframe's duplicates are fused together: the same observations, points and
    observer counts as fusing them one by one (a keyframe that saw both keeps its own view of
    the kept point)."""
    one, pairs = _fusable()
    moved_one = sum(one.fuse(keep, drop) for keep, drop in pairs)
    many, _ = _fusable()
    assert many.fuse_many(pairs) == moved_one == 4
    assert sorted(many.points) == sorted(one.points)
    for k in (1, 2, 3):
        assert many.keyframes[k].measurements == one.keyframes[k].measurements
    ids = np.array(sorted(many.points), dtype=np.int64)
    np.testing.assert_array_equal(many.observer_counts(ids), one.observer_counts(ids))
    np.testing.assert_array_equal(many.positions_of(ids), one.positions_of(ids))


def test_a_fusion_naming_a_point_twice_is_refused_before_any_point_moves() -> None:
    """A point fused away twice, or kept by one pair and fused away by another, is refused,
    and the pairs before it are not fused either: the map is as it was."""
    for bad in (lambda p: [p[0], (p[1][0], p[0][1])], lambda p: [p[0], (p[0][1], p[1][1])],
                lambda p: [p[0], (p[1][0], 10_000)]):
        m, pairs = _fusable()
        before = {k: dict(kf.measurements) for k, kf in m.keyframes.items()}
        with pytest.raises(MapError, match=r"cannot fuse|twice"):
            m.fuse_many(bad(pairs))
        assert {k: dict(kf.measurements) for k, kf in m.keyframes.items()} == before
        assert len(m.points) == 12
