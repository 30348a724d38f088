"""Keyframes into the edge's map: device ids, track ids, projection matches, new points."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.local_mapping import LocalMapping, LocalMappingConfig
from twinslam.slam.duplicate_points import duplicate_share
from twinslam.slam.keyframe import TRACK_ID_BIT

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])


def _pose(x: float) -> np.ndarray:
    p = np.eye(4)
    p[0, 3] = x
    return p


def _features(pose, world, descs, rng):
    cw = np.linalg.inv(pose)
    cam = world @ cw[:3, :3].T + cw[:3, 3]
    uv = cam[:, :2] / cam[:, 2:] * 500 + [320, 240]
    seen = (uv[:, 0] > 5) & (uv[:, 0] < 635) & (uv[:, 1] > 5) & (uv[:, 1] < 475)
    noisy = descs.copy()
    noisy[:, 0] ^= rng.integers(0, 2, len(descs), dtype=np.uint8)   # a bit or so of noise
    return seen, uv + rng.normal(0, 0.3, uv.shape), cam[:, 2], noisy


def test_integration_uses_ids_tracks_projection_and_depth() -> None:
    rng = np.random.default_rng(0)
    world = rng.uniform([-2, -1.5, 3], [2, 1.5, 6], (300, 3))
    descs = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    m = KeyFrameMap()
    m.add_keyframe(0, _pose(0.0))
    in_map = {}
    for j in range(150):                                 # the map knows the first 150 points
        in_map[j] = m.add_point(world[j], descs[j])
        m.observe(0, in_map[j])
    integ = LocalMapping(m, K, (480, 640))

    seen, uv, depth, noisy = _features(_pose(0.1), world, descs, rng)
    idx = np.flatnonzero(seen)
    ids = np.zeros(len(idx), dtype=np.uint64)
    for n, j in enumerate(idx):
        if j < 150 and j % 2 == 0:
            ids[n] = in_map[j]                           # the device associated it
        elif j >= 150:
            ids[n] = TRACK_ID_BIT | np.uint64(j)         # a new corner the device tracked
    d = depth[idx].copy()
    d[idx >= 280] = 0.0                                  # no depth there: cannot be created
    rep = integ.integrate(1, _pose(0.1), uv[idx], noisy[idx], d, ids)
    n_map = int((idx < 150).sum())
    n_new = int(((idx >= 150) & (idx < 280)).sum())
    assert rep.associated == int(((idx < 150) & (idx % 2 == 0)).sum())
    assert rep.associated + rep.matched == n_map          # the rest found by projection
    assert rep.created_from_tracks == rep.tracked == n_new
    assert rep.unused == int((idx >= 280).sum()) and rep.created == 0
    assert m.covisibility()[0, 1] == n_map
    n = int(np.flatnonzero(idx == 150)[0])              # a new point: measured where it was seen
    pid = integ.track_points[int(TRACK_ID_BIT) | 150]
    u, v, z = m.keyframes[1].measurements[pid]
    assert (u, v) == (float(uv[idx][n, 0]), float(uv[idx][n, 1])) and z == float(d[n])

    # a second keyframe carrying some of the same tracks observes the same new points
    seen2, uv2, depth2, noisy2 = _features(_pose(0.2), world, descs, rng)
    idx2 = np.flatnonzero(seen2 & (np.arange(300) >= 150) & (np.arange(300) < 280))
    ids2 = (TRACK_ID_BIT | idx2.astype(np.uint64)).astype(np.uint64)
    before = len(m.points)
    rep2 = integ.integrate(2, _pose(0.2), uv2[idx2], noisy2[idx2], depth2[idx2], ids2)
    shared = len(set(idx2) & set(idx[(idx >= 150) & (idx < 280)]))
    assert rep2.tracked == len(idx2) and rep2.created_from_tracks == len(idx2) - shared
    assert len(m.points) == before + len(idx2) - shared
    assert m.covisibility()[1, 2] == shared


def test_mismatched_lengths_are_refused() -> None:
    integ = LocalMapping(KeyFrameMap(), K, (480, 640))
    with pytest.raises(ValueError, match="keyframe 5"):
        integ.integrate(5, np.eye(4), np.zeros((3, 2)), np.zeros((2, 32), np.uint8),
                        np.zeros(3), np.zeros(3, np.uint64))


def test_a_feature_beside_a_map_point_that_looks_alike_joins_it() -> None:
    """A keyframe sees a wall the map holds, its features without ids, and ORB found each
    corner twice (two features a pixel apart, one descriptor, as it does across pyramid
    levels): the matching by pixel refuses both — two features equally alike fail its ratio
    test — so each corner would be made again, twice, beside the map's own. With fusion on
    integration the first feature whose depth puts it within 5 cm (+2 % of the depth) of the
    map's point that looks alike observes that point; the map holds no corner twice that no
    keyframe sees together."""
    rng = np.random.default_rng(1)
    world = rng.uniform([-1, -0.8, 2.0], [1, 0.8, 2.2], (120, 3))
    descs = rng.integers(0, 256, (120, 32), dtype=np.uint8)
    for join, joined in ((None, 0), (0.05, 120)):
        m = KeyFrameMap()
        m.add_keyframe(0, _pose(0.0))
        for j in range(120):
            m.observe(0, m.add_point(world[j], descs[j]))
        mapping = LocalMapping(m, K, (480, 640), LocalMappingConfig(join_radius_m=join))
        _, uv, depth, _ = _features(_pose(0.0), world, descs, rng)
        twice = np.vstack([uv, uv + np.array([1.0, 0.0])])
        report = mapping.integrate(1, _pose(0.0), twice, np.vstack([descs, descs]),
                                   np.concatenate([depth, depth]), np.zeros(240, np.uint64))
        assert report.matched == 0
        assert report.joined == joined and report.created == 240 - joined, report
        points = list(m.points.values())
        share = duplicate_share(np.array([p.position for p in points]),
                                np.array([p.descriptor for p in points]),
                                [p.observers for p in points])
        assert share == (0.0 if join else 1.0), share


def test_tracks_whose_point_left_the_map_are_forgotten_the_rest_kept_in_order() -> None:
    """The edge prunes the device-track table every slot: a track whose point was removed
    (or went with the keyframe that last saw it) is forgotten; the others keep their points
    and their order, which the checkpoint writes."""
    m = KeyFrameMap()
    m.add_keyframe(0, _pose(0.0))
    m.add_keyframe(1, _pose(0.1))
    points = [m.add_point(np.array([0.1 * j, 0.0, 4.0]), np.full(32, j, np.uint8))
              for j in range(6)]
    for j, p in enumerate(points):
        m.observe(1 if j == 5 else 0, p)
    integ = LocalMapping(m, K, (480, 640))
    tracks = [int(TRACK_ID_BIT) | (100 - j) for j in range(6)]   # not in id order
    integ.track_points.update(zip(tracks, points, strict=True))
    assert integ.forget_tracks_gone() == 0
    m.remove_point(points[2])
    m.evict(1)                                   # point 5's only keyframe
    assert integ.forget_tracks_gone() == 2
    assert list(integ.track_points.items()) == \
        [(tracks[j], points[j]) for j in (0, 1, 3, 4)]


def test_of_equally_alike_map_points_a_feature_joins_the_one_the_map_has_held_longest(
        ) -> None:
    """Corners the map holds five times over (five points within a centimetre, one
    descriptor), each seen by two features a pixel apart (the matching by pixel refuses
    both): the first joins the oldest of the five points (the lowest id), the second the
    next — the same inputs choose the same points whatever order the search visits them in,
    so a replayed run (bench.edge_scaling's devices report the point ids a recorded edge
    made) meets the ids it recorded."""
    rng = np.random.default_rng(4)
    centres = rng.uniform([-0.8, -0.6, 2.0], [0.8, 0.6, 2.4], (40, 3))
    world = np.repeat(centres, 5, axis=0) + rng.uniform(-0.005, 0.005, (200, 3))
    descs = np.repeat(rng.integers(0, 256, (40, 32), dtype=np.uint8), 5, axis=0)
    m = KeyFrameMap()
    m.add_keyframe(0, _pose(0.0))
    # each corner's five points made in a shuffled order, so that age is not the order of
    # their rows
    order = rng.permutation(200)
    ids = np.zeros(200, dtype=np.int64)
    for j in order:
        ids[j] = m.add_point(world[j], descs[j])
    for pid in ids.tolist():
        m.observe(0, pid)
    mapping = LocalMapping(m, K, (480, 640), LocalMappingConfig(join_radius_m=0.05))
    uv = centres[:, :2] / centres[:, 2:] * 500 + [320, 240]   # the keyframe at the origin
    report = mapping.integrate(1, _pose(0.0), np.vstack([uv, uv + np.array([1.0, 0.0])]),
                               np.vstack([descs[::5], descs[::5]]),
                               np.concatenate([centres[:, 2], centres[:, 2]]),
                               np.zeros(80, np.uint64))
    assert report.matched == 0 and report.joined == 80, report
    for corner in range(40):
        five = sorted(ids[5 * corner:5 * corner + 5].tolist())
        assert set(five[:2]) == set(five) & m.keyframes[1].points
