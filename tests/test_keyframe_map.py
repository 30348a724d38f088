"""The edge's keyframe map: covisibility from shared points, eviction, checkpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from twinslam.slam.back_end.foreign_keyframes import foreign_tag
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame
from twinslam.slam.back_end.keyframe_map import Incidence, KeyFrameMap, MapError, shared_counts
from twinslam.slam.back_end.point_columns import PointColumns


def _map() -> KeyFrameMap:
    """Keyframes 10, 11, 12; points shared 10–11 (3), 11–12 (2), 10–12 (1)."""
    m = KeyFrameMap()
    for k in (10, 11, 12):
        pose = np.eye(4)
        pose[0, 3] = k
        m.add_keyframe(k, pose)
    rng = np.random.default_rng(0)
    links = {(10, 11): 3, (11, 12): 2, (10, 12): 1, (10,): 4}
    for kfs, count in links.items():
        for _ in range(count):
            pid = m.add_point(rng.normal(size=3), rng.integers(0, 256, 32, dtype=np.uint8))
            for k in kfs:
                m.observe(k, pid, (float(pid), float(k)), 1.5 if pid % 2 else float("nan"))
    return m


def test_covisibility_counts_shared_points() -> None:
    m = _map()
    np.testing.assert_array_equal(m.covisibility(), [[0, 3, 1], [3, 0, 2], [1, 2, 0]])
    assert m.shared_points(m.keyframes[11].points).tolist() == [3, 5, 2]


def test_evicting_a_keyframe_drops_its_links_and_orphaned_points() -> None:
    m = _map()
    n_points = len(m.points)
    orphans = m.evict(10)
    assert len(orphans) == 4                             # seen by keyframe 10 alone
    assert len(m.points) == n_points - 4
    np.testing.assert_array_equal(m.covisibility(), [[0, 2], [2, 0]])
    assert all(10 not in p.observers for p in m.points.values())
    with pytest.raises(MapError, match="keyframe 10"):
        m.evict(10)
    with pytest.raises(MapError, match="point 9999"):
        m.observe(11, 9999)


def test_checkpoint_round_trip_and_refusals(tmp_path: Path) -> None:
    m = _map()
    m.evict(12)
    for n, point in enumerate(m.points.values()):      # the culling's counts come back too
        point.visible, point.found = 3 + n, 1 + n
    path = tmp_path / "map.npz"
    m.save(path, slot=np.array(7))
    again, extra = KeyFrameMap.load(path)
    assert int(extra["slot"]) == 7
    assert again.keyframe_ids() == [10, 11]
    np.testing.assert_array_equal(again.covisibility(), m.covisibility())
    np.testing.assert_array_equal(again.keyframes[11].pose, m.keyframes[11].pose)
    assert {p: (tuple(v.position), bytes(v.descriptor), v.observers, v.visible, v.found)
            for p, v in again.points.items()} == \
        {p: (tuple(v.position), bytes(v.descriptor), v.observers, v.visible, v.found)
         for p, v in m.points.items()}
    for k in (10, 11):
        np.testing.assert_equal(again.keyframes[k].measurements, m.keyframes[k].measurements)
    assert again.add_point(np.zeros(3), np.zeros(32, np.uint8)) == m.next_point_id
    assert not (tmp_path / "map.npz.tmp").exists()
    KeyFrameMap().save(tmp_path / "empty.npz")        # an edge before its first keyframe
    empty, _ = KeyFrameMap.load(tmp_path / "empty.npz")
    assert not empty.keyframes and not empty.points
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    with pytest.raises(MapError, match=r"bad\.npz"):
        KeyFrameMap.load(tmp_path / "bad.npz")


def test_points_read_together_as_each_reads_alone_through_rows_freed_and_grown() -> None:
    """The map's columns give any set of points at once: after points left (their rows taken
    by new points) and the columns outgrew their first capacity, every point still reads its
    own position and descriptor, alone or many at once."""
    m = KeyFrameMap()
    m.add_keyframe(1, np.eye(4))
    rng = np.random.default_rng(3)
    made: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for _ in range(3000):                               # past the first 1024 rows
        xyz, desc = rng.normal(size=3), rng.integers(0, 256, 32, dtype=np.uint8)
        pid = m.add_point(xyz, desc)
        m.observe(1, pid)
        made[pid] = (xyz, desc)
        if pid % 3 == 0:                                # leaves: its row goes to a newer one
            m.remove_point(pid)
            del made[pid]
    m.add_keyframe(2, np.eye(4))
    ids = sorted(made)
    m.observe_many(2, ids[::2], [[0.0, 0.0]] * len(ids[::2]), [1.0] * len(ids[::2]))
    m.unobserve(2, ids[0])
    m.fuse(ids[2], ids[1])                              # 2 observes both: 1 leaves
    del made[ids[1]]
    both = sorted(m.points)
    np.testing.assert_array_equal(m.observer_counts(both),
                                  [len(m.points[p].observers) for p in both])
    assert set(m.observer_counts(both).tolist()) == {1, 2}
    m.evict(1)                                          # the points 2 did not see leave
    made = {p: made[p] for p in m.points}
    ids = sorted(made, reverse=True)
    assert len(ids) == len(m.columns) > 1024 // 2
    np.testing.assert_array_equal(m.observer_counts(ids),
                                  [len(m.points[p].observers) for p in ids])
    np.testing.assert_array_equal(m.positions_of(ids), [made[p][0] for p in ids])
    np.testing.assert_array_equal(m.descriptors_of(ids), [made[p][1] for p in ids])
    assert all(np.array_equal(m.points[p].position, made[p][0]) for p in ids)
    assert m.positions_of([]).shape == (0, 3)


def test_a_point_reads_as_a_value_and_keeps_it_when_it_leaves() -> None:
    """A position read is the point's as it was then (a loop moving the point later does not
    change what a caller kept), and a point that left the map still reads what it last had,
    though a new point took its row."""
    m = KeyFrameMap()
    m.add_keyframe(1, np.eye(4))
    pid = m.add_point(np.array([1.0, 2.0, 3.0]), np.full(32, 7, np.uint8))
    m.observe(1, pid)
    kept = m.points[pid].position
    kept[0] = 99.0                                      # a caller's copy, not the map
    np.testing.assert_array_equal(m.points[pid].position, [1.0, 2.0, 3.0])
    m.set_positions([pid], np.array([[4.0, 5.0, 6.0]]))
    np.testing.assert_array_equal(kept, [99.0, 2.0, 3.0])
    point = m.points[pid]
    m.remove_point(pid)
    newer = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
    m.observe(1, newer)
    np.testing.assert_array_equal(point.position, [4.0, 5.0, 6.0])
    np.testing.assert_array_equal(point.descriptor, np.full(32, 7, np.uint8))
    with pytest.raises(ValueError, match="2 positions"):
        m.set_positions([newer], np.zeros((2, 3)))
    # the points only an evicted keyframe observed leave with it, all at once: each keeps
    # its own values and view counts, though newer points take their rows
    m.add_keyframe(2, np.eye(4))
    alone = m.add_points(np.arange(12.0).reshape(4, 3), np.arange(128, dtype=np.uint8
                                                                    ).reshape(4, 32))
    m.observe_many(2, alone, [[0.0, 0.0]] * 4, [1.0] * 4)
    m.observe(2, newer)
    m.points[alone[1]].visible, m.points[alone[1]].found = 9, 4
    leaving = [m.points[q] for q in alone]
    assert m.evict(2) == alone and newer in m.points
    m.add_points(np.zeros((4, 3)), np.zeros((4, 32), np.uint8))
    for j, left in enumerate(leaving):
        np.testing.assert_array_equal(left.position, np.arange(12.0).reshape(4, 3)[j])
        assert bytes(left.descriptor) == bytes(range(32 * j, 32 * j + 32))
    assert (leaving[1].visible, leaving[1].found) == (9, 4)
    assert (leaving[0].visible, leaving[0].found) == (1, 1)


def _as_dicts(m: KeyFrameMap) -> dict[int, dict[int, tuple[float, ...]]]:
    """Every keyframe's observations as :meth:`KeyFrame.observed` gives them."""
    out = {}
    for k, kf in m.keyframes.items():
        ids, uvd = kf.observed()
        out[k] = {int(p): tuple(float(x) for x in row) for p, row in zip(ids, uvd, strict=True)}
    return out


def test_the_observations_kept_as_arrays_follow_every_edit(tmp_path: Path) -> None:
    """The checkpoint and the loop closer's snapshot read each keyframe's observations from
    arrays it keeps between slots: after each kind of edit (observe, unobserve, fuse, a point
    removed) they must be the keyframe's observations as they are now, never as they were
    when first read — the checkpoint written then loads back the same observations."""
    m = _map()
    _as_dicts(m)                                      # every keyframe's arrays kept
    new = m.add_point(np.zeros(3), np.zeros(32, np.uint8))
    m.observe(11, new, (1.0, 2.0), 0.5)
    shared = sorted(m.keyframes[10].points & m.keyframes[11].points)
    m.unobserve(10, shared[0])
    # keyframe 10 sees the dropped point and not the kept one: as many observations as
    # before, one of them another point's now
    only_10 = sorted(m.keyframes[10].points - m.keyframes[11].points - m.keyframes[12].points)
    not_10 = sorted(m.keyframes[12].points - m.keyframes[10].points)
    m.fuse(not_10[0], only_10[0])
    m.remove_point(sorted(m.keyframes[12].points)[0])
    np.testing.assert_equal(_as_dicts(m), {k: dict(kf.measurements)
                                           for k, kf in m.keyframes.items()})
    archived = ArchivedKeyFrame.of(m, 11, slot=3)
    assert archived.point_ids.tolist() == sorted(m.keyframes[11].points)
    np.testing.assert_array_equal(
        archived.measurements, [m.keyframes[11].measurements[p] for p in sorted(
            m.keyframes[11].points)])
    m.save(tmp_path / "map.npz")
    again, _ = KeyFrameMap.load(tmp_path / "map.npz")
    for k in m.keyframes:
        np.testing.assert_equal(again.keyframes[k].measurements, m.keyframes[k].measurements)
        assert list(again.keyframes[k].measurements) == list(m.keyframes[k].measurements)


def test_a_checkpoint_keeps_each_points_values_whatever_order_the_points_came_in(
        tmp_path: Path) -> None:
    """Points come back under their old ids (a restored keyframe's) or under another device's
    tagged ids after newer ones: the checkpoint, read in the order the points came and
    written in id order, must give each point its own position, descriptor and view
    counts."""
    m = _map()
    gone = sorted(m.keyframes[10].points - m.keyframes[11].points - m.keyframes[12].points)[0]
    position, descriptor = m.points[gone].position, m.points[gone].descriptor
    m.remove_point(gone)
    m.add_point(np.full(3, 9.0), np.full(32, 9, np.uint8))          # a newer point first
    m.readd_point(gone, position, descriptor)                         # then an old id again
    m.observe(10, gone, (1.0, 1.0), 1.0)
    for n, point in enumerate(m.points.values()):
        point.visible, point.found = 10 + n, n
    m.save(tmp_path / "map.npz")
    again, _ = KeyFrameMap.load(tmp_path / "map.npz")
    assert list(m.points)[-1] == gone                  # not the order of ids
    assert {p: (tuple(v.position), bytes(v.descriptor), v.visible, v.found)
            for p, v in again.points.items()} == \
        {p: (tuple(v.position), bytes(v.descriptor), v.visible, v.found)
         for p, v in m.points.items()}


def test_points_added_at_once_are_as_points_added_one_by_one() -> None:
    """Integration makes a keyframe's hundreds of points at once and a restore brings them
    back at once: the next ids in order, the rows, values and view counts one-by-one adding
    gives (freed rows taken first), and a point named twice or still in the map refused."""
    rng = np.random.default_rng(8)
    xyz, desc = rng.normal(size=(30, 3)), rng.integers(0, 256, (30, 32), dtype=np.uint8)
    one, many = KeyFrameMap(), KeyFrameMap()
    for m in (one, many):
        for j in range(5):
            m.add_point(xyz[j], desc[j])
        m.remove_point(2)
        m.remove_point(4)
    singly = [one.add_point(xyz[j], desc[j]) for j in range(5, 30)]
    assert many.add_points(xyz[5:], desc[5:]) == singly == list(range(6, 31))
    assert many.columns.row == one.columns.row
    for p in singly:
        assert np.array_equal(many.points[p].position, one.points[p].position)
        assert bytes(many.points[p].descriptor) == bytes(one.points[p].descriptor)
        assert (many.points[p].visible, many.points[p].found) == (1, 1)
    many.readd_points([2, 4], xyz[[2, 4]], desc[[2, 4]])
    assert np.array_equal(many.points[4].position, xyz[4]) and 2 in many.points
    with pytest.raises(MapError, match="cannot come back"):
        many.readd_points([3], xyz[:1], desc[:1])
    with pytest.raises(MapError, match="cannot come back"):
        many.readd_points([99], xyz[:1], desc[:1])
    with pytest.raises(MapError, match="positions"):
        many.add_points(xyz[:2], desc[:1])
    many.remove_point(1)
    with pytest.raises(MapError, match="twice"):
        many.readd_points([1, 1], xyz[:2], desc[:2])
    assert 1 not in many.points and 1 not in many.columns.row
    assert many.add_points(np.zeros((0, 3)), np.zeros((0, 32), np.uint8)) == []


def _counted_from_scratch(m: KeyFrameMap) -> np.ndarray:
    return shared_counts([np.array(sorted(m.keyframes[k].points), dtype=np.int64)
                          for k in m.keyframe_ids()])


def test_the_covisibility_kept_between_reads_follows_every_edit() -> None:
    """The map keeps the last covisibility it counted (the slot's end and the next slot's
    plan read the same map): read again unedited it is the one kept; after each kind of edit
    (observe, unobserve, fuse, a point removed, a keyframe evicted or added) it is counted
    again, and always what counting the keyframes' points from scratch gives."""
    m = _map()
    first = m.incidence(m.keyframe_ids())
    assert m.incidence(m.keyframe_ids()) is first
    np.testing.assert_array_equal(m.covisibility(), _counted_from_scratch(m))
    shared = sorted(m.keyframes[10].points & m.keyframes[11].points)
    only_10 = sorted(m.keyframes[10].points - m.keyframes[11].points - m.keyframes[12].points)
    edits = [lambda: m.observe(12, shared[0], (1.0, 2.0), 0.5),
             lambda: m.unobserve(10, shared[1]),
             lambda: m.fuse(sorted(m.keyframes[12].points)[0], only_10[0]),
             lambda: m.remove_point(shared[2]),
             lambda: m.add_keyframe(13, np.eye(4)),
             lambda: m.evict(11)]
    for edit in edits:
        before = m.covisibility()
        edit()
        np.testing.assert_array_equal(m.covisibility(), _counted_from_scratch(m))
        assert m.covisibility() is not before
    with pytest.raises(ValueError, match="read-only"):
        m.covisibility()[0, 1] = 5.0


def test_frames_counted_against_a_maps_kept_incidence_are_counted_as_from_scratch() -> None:
    """A slot's frames (map points, track keys as negative ids, points the map lacks) counted
    against the keyframes' kept incidence: the same weights as all the sets counted at once."""
    rng = np.random.default_rng(5)
    keyframes = [rng.choice(300, 50, replace=False).astype(np.int64) for _ in range(6)]
    frames = [np.concatenate([rng.choice(400, 40, replace=False), -1 - rng.choice(30, 10,
                                                                                 replace=False)])
              .astype(np.int64) for _ in range(5)] + [np.zeros(0, dtype=np.int64)]
    counted = Incidence.of(range(6), keyframes)
    np.testing.assert_array_equal(counted.extended(frames), shared_counts(keyframes + frames))
    np.testing.assert_array_equal(counted.extended([]), shared_counts(keyframes))
    none = Incidence.of([], [])
    np.testing.assert_array_equal(none.extended(frames), shared_counts(frames))


def test_rows_read_by_an_array_of_ids_are_the_rows_each_id_has() -> None:
    """Ids given as an array find their rows at once (the map's own, through removals, reused
    rows and growth past the first capacity; another device's tagged ids; uint64 as the wire
    carries them): the rows id by id gives, and an id the map lacks is refused as it is id by
    id. Every point in id order is what sorting them gives; which ids have a row, asked at
    once, is what the rows by id say."""
    columns = PointColumns(capacity=8)
    rng = np.random.default_rng(1)
    own = list(range(1, 40))
    columns.add_many(own, rng.normal(size=(39, 3)), np.zeros((39, 32), np.uint8))
    foreign = [foreign_tag(3) | p for p in (5, 6, 7)]
    columns.add_many(foreign, rng.normal(size=(3, 3)), np.zeros((3, 32), np.uint8))
    for gone in (4, 17, 30):
        columns.remove(gone)
    columns.add_many([40, 41, 300], rng.normal(size=(3, 3)), np.zeros((3, 32), np.uint8))
    held = [p for p in [*own, 40, 41, 300] if p not in (4, 17, 30)][::-1]
    for ids in (held, foreign + held[:5], [300]):
        by_id = [columns.row[p] for p in ids]
        for kind in (np.int64, np.uint64):
            rows = columns.rows_of(np.array(ids, dtype=kind))
            assert rows.dtype == np.int64 and rows.tolist() == by_id
        assert columns.rows_of(ids).tolist() == by_id
    assert columns.rows_of(np.zeros(0, dtype=np.int64)).tolist() == []
    # every point in id order, as sorting them all gives
    ids, rows = columns.ids_and_rows()
    order = np.argsort(ids)
    for got, want in zip(columns.by_id(), (ids[order], rows[order]), strict=True):
        assert got.dtype == np.int64 and got.tolist() == want.tolist()
    columns.remove(foreign[1])
    assert columns.by_id()[0].tolist() == sorted(columns.row)
    # which ids have a row, asked at once, as the dict of rows answers id by id
    asked = [*held[:3], 4, 17, 10_000, -3, *foreign, foreign_tag(3) | 8, 300]
    assert columns.holds(np.array(asked, dtype=np.int64)).tolist() == \
        [p in columns.row for p in asked]
    assert columns.holds(np.zeros(0, dtype=np.int64)).tolist() == []
    for missing in ([17], [41, 4], [10_000], [foreign_tag(3) | 8], [foreign[0], 17],
                    [41, foreign_tag(3) | 8]):
        with pytest.raises(KeyError):
            columns.rows_of(np.array(missing, dtype=np.int64))


def test_ids_past_the_dense_range_are_found_though_the_rows_by_id_reach_past_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """An id at or past the dense range has its row in the dict even where the rows by id,
    grown by doubling, reach past that range: read at once, asked whether held, and refused
    when not, as id by id."""
    monkeypatch.setattr("twinslam.slam.back_end.point_columns.DENSE_IDS", 48)
    columns = PointColumns(capacity=4)
    rng = np.random.default_rng(2)
    ids = [3, 40, 47, 48, 60, 70]
    columns.add_many(ids, rng.normal(size=(6, 3)), np.zeros((6, 32), np.uint8))
    assert len(columns._row_by_id) > 48          # the case: rows by id reach past the range
    asked = np.array([60, 3, 48, 70, 40], dtype=np.int64)
    assert columns.rows_of(asked).tolist() == [columns.row[p] for p in asked.tolist()]
    assert columns.holds(np.array([48, 49, 60, 2], dtype=np.int64)).tolist() == \
        [True, False, True, False]
    with pytest.raises(KeyError):
        columns.rows_of(np.array([3, 50], dtype=np.int64))


def test_points_keep_their_rows_and_order_through_leaving_and_coming_back() -> None:
    """The map's own points and another device's (tagged ids, kept sorted apart from the rows
    by id) come, leave one by one — past the points where the entries of those that left are
    dropped — and some come back under the same ids: every question about them is answered
    as the dict of rows answers it, at every step, every point listed in the order it came."""
    columns = PointColumns(capacity=4)
    rng = np.random.default_rng(7)
    tags = [foreign_tag(2), foreign_tag(5)]
    pool = [*range(1, 60), *(tag | p for tag in tags for p in range(1, 120))]
    held: list[int] = []
    for step in range(40):
        out = [p for p in pool if p not in columns.row]
        come = [int(p) for p in rng.choice(out, size=min(len(out), int(rng.integers(1, 25))),
                                           replace=False)]
        columns.add_many(come, rng.normal(size=(len(come), 3)),
                         np.zeros((len(come), 32), np.uint8))
        held += come
        for gone in rng.permutation(held)[:int(rng.integers(0, len(held)))].tolist():
            columns.remove(gone)
            held.remove(gone)
        assert len(held) == len(columns.row)
        asked = np.array(pool, dtype=np.int64)
        assert columns.holds(asked).tolist() == [p in columns.row for p in pool]
        if held:
            assert columns.rows_of(np.array(held, dtype=np.int64)).tolist() == \
                [columns.row[p] for p in held]
        assert columns.by_id()[0].tolist() == sorted(columns.row), step
        ids, rows = columns.ids_and_rows()
        assert ids.tolist() == list(columns.row) and rows.tolist() == list(columns.row.values())
        missing = [p for p in pool if p not in columns.row][:1]
        if missing:
            with pytest.raises(KeyError):
                columns.rows_of(np.array([*held[:2], *missing], dtype=np.int64))
