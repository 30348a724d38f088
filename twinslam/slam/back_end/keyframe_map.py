"""The edge's keyframe map: keyframes, map points, who observes what, and a checkpoint.

ORB-SLAM's ``Map`` with ``KeyFrame`` and ``MapPoint``, reduced to what edge-assisted map
management needs: the covisibility weight of two keyframes is the number of map points both
observe, w(f, f') = |M_f ∩ M_f'| (paper §III-B), and evicting a keyframe removes its
observations, and with them the points nobody observes any more (they cannot be optimised).

The checkpoint is one ``.npz`` written to a temporary file and renamed over the old one, so a
crash mid-write leaves the previous checkpoint intact; the edge node writes it every slot and
restores from it after a restart.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain, repeat
from operator import attrgetter
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from twinslam.npz_files import NPZ_READ_ERRORS, write_npz
from twinslam.slam.back_end.foreign_keyframes import is_foreign
from twinslam.slam.back_end.point_columns import PointColumns
from twinslam.slam.sorted_ids import find_sorted, unique_ids_and_inverse

CHECKPOINT_FORMAT = "twinslam-keyframe-map-1"


class MapError(ValueError):
    """An inconsistent edit (unknown keyframe or point) or an unreadable checkpoint."""


@dataclass
class KeyFrame:
    id: int
    pose: np.ndarray                       #: 4×4 camera-to-map
    points: set[int] = field(default_factory=set)   #: M_f: ids of the map points it observes
    #: where it saw each point: (u, v, depth in metres or NaN) — the bundle adjustment's data
    measurements: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    #: the 3×3 intrinsics of the camera that took it, where that is not the camera of the
    #: device whose map this is (another device's keyframe: its pixels mean other rays);
    #: None: the map's own device's
    intrinsics: np.ndarray | None = None
    #: :meth:`observed`'s arrays, until the map edits its observations
    _observed: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False,
                                                             repr=False, compare=False)

    def observed(self) -> tuple[np.ndarray, np.ndarray]:
        """Its observations as arrays, in the order it came to observe the points: their ids
        ((n,) int64) and where it saw them ((n, 3): u, v, depth), read-only. The checkpoint
        and the loop closer's snapshot read every keyframe's each slot, and most keyframes'
        did not change since the last: the arrays are kept until :class:`KeyFrameMap` edits
        the observations (observe, unobserve, fuse, a point removed: :meth:`edited`)."""
        kept = self._observed
        if kept is not None and len(kept[0]) == len(self.measurements):
            return kept
        meas = self.measurements
        n = len(meas)
        ids = np.fromiter(meas, dtype=np.int64, count=n)
        uvd = np.fromiter(chain.from_iterable(meas.values()), dtype=np.float64,
                          count=3 * n).reshape(n, 3)
        ids.flags.writeable = uvd.flags.writeable = False
        self._observed = (ids, uvd)
        return self._observed

    def edited(self) -> None:
        """Its observations changed: :meth:`observed` reads them again."""
        self._observed = None


class MapPoint:
    """A map point: its observers here; its position (xyz in the map frame), representative
    32-byte ORB descriptor and view counts in the map's :class:`PointColumns` row. They read
    as copies and are written by assignment (``point.position = xyz``, ``point.visible += 1``),
    as when each point held values of its own; a point that left the map keeps what it last
    had."""

    __slots__ = ("_columns", "_kept", "_row", "id", "observers")

    def __init__(self, point_id: int, columns: PointColumns, row: int) -> None:
        self.id = point_id
        self.observers: set[int] = set()     #: keyframe ids
        self._columns = columns
        self._row = row
        #: once it left the map: its position, descriptor, visible and found counts
        self._kept: tuple[np.ndarray, np.ndarray, int, int] | None = None

    @property
    def position(self) -> np.ndarray:
        xyz: np.ndarray = (self._kept[0] if self._kept is not None
                           else self._columns.positions[self._row])
        return xyz.copy()

    @position.setter
    def position(self, xyz: np.ndarray) -> None:
        if self._kept is not None:
            self._kept = (np.asarray(xyz, dtype=np.float64).reshape(3).copy(),
                          *self._kept[1:])
        else:
            self._columns.positions[self._row] = xyz

    @property
    def descriptor(self) -> np.ndarray:
        desc: np.ndarray = (self._kept[1] if self._kept is not None
                            else self._columns.descriptors[self._row])
        return desc.copy()

    @property
    def visible(self) -> int:
        """Keyframes whose view held it (its creator counted): the found ratio's denominator
        (:mod:`twinslam.slam.back_end.point_culling`)."""
        return self._kept[2] if self._kept is not None \
            else int(self._columns.visible[self._row])

    @visible.setter
    def visible(self, count: int) -> None:
        if self._kept is not None:
            self._kept = (self._kept[0], self._kept[1], int(count), self._kept[3])
        else:
            self._columns.visible[self._row] = count

    @property
    def found(self) -> int:
        """Keyframes of those that observed it (its creator counted)."""
        return self._kept[3] if self._kept is not None \
            else int(self._columns.found[self._row])

    @found.setter
    def found(self, count: int) -> None:
        if self._kept is not None:
            self._kept = (self._kept[0], self._kept[1], self._kept[2], int(count))
        else:
            self._columns.found[self._row] = count

    def keep(self, position: np.ndarray, descriptor: np.ndarray, visible: int, found: int
             ) -> None:
        """The point left the map with these values (its row's, read by the map — for many
        points at once), which it reads from now on."""
        self._kept = (position, descriptor, int(visible), int(found))


#: a point's observer set and its row in the columns, read at C speed over many points
_OBSERVERS = attrgetter("observers")
_ROW = attrgetter("_row")


def _run(calls: Iterator[object]) -> None:
    """Make every call of a lazy ``map`` (its results unused), at C speed: itertools' consume
    recipe."""
    deque(calls, maxlen=0)


def stacked_rows(rows: list[np.ndarray], shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """Equal-shaped arrays as one array of ``(len(rows), *shape)``, also when there are none
    (``np.concatenate`` copies each row's buffer at once; ``np.array`` reads it element by
    element)."""
    if not rows:
        return np.zeros((0, *shape), dtype=dtype)
    return np.concatenate(rows).astype(dtype, copy=False).reshape(-1, *shape)


def point_incidence(sets: list[np.ndarray]) -> tuple[np.ndarray, sparse.csr_matrix]:
    """The ids the sets (int64 arrays without repeats) hold, sorted, and the sets × ids
    incidence matrix (a 1 where set a holds id j)."""
    keys = np.concatenate(sets) if sets else np.zeros(0, dtype=np.int64)
    ids, cols = unique_ids_and_inverse(keys)
    indptr = np.concatenate([[0], np.cumsum([len(s) for s in sets], dtype=np.int64)])
    inc = sparse.csr_matrix((np.ones(len(keys)), cols, indptr),   # rows contiguous
                            shape=(len(sets), len(ids)))
    return ids, inc


def shared_counts(sets: list[np.ndarray]) -> np.ndarray:
    """|S_a ∩ S_b| for every pair of id sets (int64 arrays without repeats), zero diagonal:
    one sparse product of the sets × ids incidence matrix with its transpose — milliseconds
    where pairwise Python set intersections took ~0.3 s for a slot against a full map."""
    if not sets:
        return np.zeros((0, 0))
    return counts_of(point_incidence(sets)[1])


def counts_of(incidence: sparse.csr_matrix) -> np.ndarray:
    """:func:`shared_counts` of the sets an incidence matrix (:func:`point_incidence`) holds."""
    w = (incidence @ incidence.T).toarray()
    np.fill_diagonal(w, 0.0)
    return np.asarray(w)


@dataclass(frozen=True, eq=False)
class Incidence:
    """Keyframes' point sets (``sets``, in the order of ``ids``) as the sets × points
    incidence (``points``: the ids they hold, sorted) and their shared counts (``weights``,
    zero diagonal, read-only): what the map's uncertainty, the slot planner and the restores
    each read of the map every slot. :meth:`extended` counts further sets against them
    without counting the keyframes' pairs again."""

    ids: tuple[int, ...]
    sets: tuple[np.ndarray, ...]
    points: np.ndarray
    matrix: sparse.csr_matrix
    weights: np.ndarray

    @classmethod
    def of(cls, ids: Sequence[int], sets: Sequence[np.ndarray]) -> Incidence:
        points, matrix = point_incidence(list(sets))
        weights = counts_of(matrix)
        weights.flags.writeable = False
        return cls(tuple(ids), tuple(sets), points, matrix, weights)

    def holds(self, ids: Sequence[int], sets: Sequence[np.ndarray]) -> bool:
        """Whether these are the sets it was made of (the very arrays: a keyframe's array is
        made again whenever the map edits its observations, :meth:`KeyFrame.observed`)."""
        return tuple(ids) == self.ids and all(
            a is b for a, b in zip(sets, self.sets, strict=True))

    def extended(self, others: Sequence[np.ndarray]) -> np.ndarray:
        """:func:`shared_counts` of its sets followed by ``others`` (int64 arrays without
        repeats: a slot's frames, keyframes on their way): the others' counts with the
        keyframes through the points the keyframes hold, found by a sorted search, and
        among themselves from scratch; the keyframes' among themselves as they are."""
        n, k = len(self.ids), len(others)
        w = np.zeros((n + k, n + k))
        w[:n, :n] = self.weights
        if not k:
            return w
        keys = np.concatenate(others)
        owner = np.repeat(np.arange(k), [len(o) for o in others])
        col, held = find_sorted(self.points, keys)
        theirs = sparse.csr_matrix((np.ones(int(held.sum())), (owner[held], col[held])),
                                   shape=(k, len(self.points)))
        across = (theirs @ self.matrix.T).toarray()
        w[n:, :n] = across
        w[:n, n:] = across.T
        w[n:, n:] = shared_counts(list(others))
        return w


def shared_pairs(ids: Sequence[int], points: Mapping[int, np.ndarray]
                 ) -> dict[tuple[int, int], int]:
    """The map points pairs of keyframes (a < b, of ``ids``; ``points``: each keyframe's point
    ids, int64 without repeats, none for a keyframe it lacks) share: each consecutive pair of
    ``ids`` (by id: how stiff a step of the walk is, 0 included) and every other pair that
    shares any (the covisibility that holds keyframes seeing one place together)."""
    ids = sorted(ids)
    empty = np.zeros(0, dtype=np.int64)
    counts = shared_counts([points.get(k, empty) for k in ids])
    shared = {(a, b): 0 for a, b in itertools.pairwise(ids)}
    rows, cols = np.nonzero(np.triu(counts, 1))
    shared.update({(ids[i], ids[j]): int(counts[i, j])
                   for i, j in zip(rows.tolist(), cols.tolist(), strict=True)})
    return shared


class KeyFrameMap:
    """Keyframes and map points with their observation links kept both ways."""

    def __init__(self) -> None:
        self.keyframes: dict[int, KeyFrame] = {}
        self.points: dict[int, MapPoint] = {}
        #: the points' positions and descriptors, a row a point (read many at once with
        #: :meth:`positions_of` and :meth:`descriptors_of`)
        self.columns = PointColumns()
        self.next_point_id = 1                   #: 0 means "no point" on the wire
        self._incidence: Incidence | None = None  #: the last one asked for, while it holds

    # -- edits -----------------------------------------------------------------------------

    def add_keyframe(self, kf_id: int, pose: np.ndarray,
                     intrinsics: np.ndarray | None = None) -> KeyFrame:
        """A keyframe at ``pose``, taken by a camera of ``intrinsics`` where that is not the
        map's own device's (None)."""
        if kf_id in self.keyframes:
            raise MapError(f"keyframe {kf_id} is already in the map")
        kf = KeyFrame(kf_id, np.asarray(pose, dtype=np.float64).copy(),
                      intrinsics=None if intrinsics is None
                      else np.asarray(intrinsics, dtype=np.float64).reshape(3, 3).copy())
        self.keyframes[kf_id] = kf
        return kf

    def add_point(self, position: np.ndarray, descriptor: np.ndarray) -> int:
        """A new map point; returns its id."""
        return self.add_points(np.asarray(position, dtype=np.float64).reshape(1, 3),
                               np.asarray(descriptor, dtype=np.uint8).reshape(1, 32))[0]

    def add_points(self, positions: np.ndarray, descriptors: np.ndarray) -> list[int]:
        """New map points at once ((n, 3) positions, (n, 32) descriptors); their ids, the
        next ``n`` (:attr:`next_point_id` onwards, in order)."""
        n = len(positions)
        ids = list(range(self.next_point_id, self.next_point_id + n))
        self._put_points(ids, positions, descriptors)
        self.next_point_id += n
        return ids

    def readd_points(self, point_ids: list[int], positions: np.ndarray, descriptors: np.ndarray
                     ) -> None:
        """:meth:`readd_point` of many points at once (a keyframe restored from the archive
        brings back hundreds)."""
        for point_id in point_ids:
            if point_id in self.points or not (0 < point_id < self.next_point_id
                                               or is_foreign(point_id)):
                raise MapError(f"point {point_id} cannot come back: it is in the map or was "
                               "never one of it")
        self._put_points(point_ids, positions, descriptors)

    def _put_points(self, point_ids: list[int], positions: np.ndarray, descriptors: np.ndarray
                    ) -> None:
        if len(positions) != len(point_ids) or len(descriptors) != len(point_ids):
            raise MapError(f"{len(point_ids)} points but {len(positions)} positions and "
                           f"{len(descriptors)} descriptors")
        if len(set(point_ids)) != len(point_ids):
            raise MapError("a point is named twice among the points added")
        rows = self.columns.add_many(point_ids, positions, descriptors).tolist()
        columns = self.columns
        self.points.update((p, MapPoint(p, columns, r))
                           for p, r in zip(point_ids, rows, strict=True))

    def readd_point(self, point_id: int, position: np.ndarray, descriptor: np.ndarray) -> None:
        """Put back a point the map had (``point_id`` below ``next_point_id``: ids are never
        reused, so it cannot clash with a newer point) and has no more — a keyframe restored
        from the edge's archive brings its points back under their own ids — or another
        device's point, under its tagged id (:mod:`~twinslam.slam.back_end.foreign_keyframes`),
        which no point of this map's own can take."""
        self.readd_points([point_id], np.asarray(position, dtype=np.float64).reshape(1, 3),
                          np.asarray(descriptor, dtype=np.uint8).reshape(1, 32))

    def _drop_points(self, point_ids: list[int]) -> None:
        """:meth:`_drop_point` of many points at once (a keyframe evicted takes the hundreds
        only it observed with it): what each had read from the columns in one go."""
        if not point_ids:
            return
        columns = self.columns
        rows = columns.rows_of(point_ids)
        kept = zip(columns.positions[rows], columns.descriptors[rows],
                   columns.visible[rows].tolist(), columns.found[rows].tolist(), strict=True)
        for point_id, values in zip(point_ids, kept, strict=True):
            self.points.pop(point_id).keep(*values)
            columns.remove(point_id)

    def _drop_point(self, point_id: int) -> MapPoint:
        """Take a point out of the map (its row freed); returns it, holding what it had."""
        point = self.points[point_id]
        self._drop_points([point_id])
        return point

    def observe(self, kf_id: int, point_id: int,
                uv: tuple[float, float] = (math.nan, math.nan), depth: float = math.nan
                ) -> None:
        """Keyframe ``kf_id`` sees point ``point_id`` at pixel ``uv`` (with ``depth``)."""
        self.observe_many(kf_id, [point_id], [[float(uv[0]), float(uv[1])]], [float(depth)])

    def observe_many(self, kf_id: int, point_ids: list[int], uvs: list[list[float]],
                     depths: list[float]) -> None:
        """``observe`` for many points of one keyframe (its integration's bulk path: hundreds
        of observations a keyframe, each point's observers and count written by C-level
        iteration, not a Python step a point)."""
        if not len(uvs) == len(depths) == len(point_ids):
            raise ValueError(f"{len(point_ids)} points but {len(uvs)} pixels and "
                             f"{len(depths)} depths")
        kf = self.keyframes.get(kf_id)
        try:
            seen = list(map(self.points.__getitem__, point_ids))
        except KeyError:
            seen = []
        if kf is None or len(seen) != len(point_ids):
            missing = [p for p in point_ids if p not in self.points]
            named = ", ".join(str(p) for p in (missing or point_ids)[:5])
            raise MapError(f"keyframe {kf_id} cannot observe point {named}: unknown "
                           "keyframe or point")
        kf.points.update(point_ids)
        kf.edited()
        kf.measurements.update(zip(point_ids, [(u, v, d) for (u, v), d
                                               in zip(uvs, depths, strict=True)], strict=True))
        _run(map(set.add, map(_OBSERVERS, seen), repeat(kf_id)))
        self._count_observers_of(seen)

    def unobserve(self, kf_id: int, point_id: int) -> bool:
        """Drop one observation (an outlier the optimiser found); removes the point when it
        was its last observer and returns True then."""
        kf, pt = self.keyframes[kf_id], self.points[point_id]
        kf.points.discard(point_id)
        kf.measurements.pop(point_id, None)
        kf.edited()
        pt.observers.discard(kf_id)
        if not pt.observers:
            self._drop_point(point_id)
            return True
        self._count_observers([point_id])
        return False

    def remove_point(self, point_id: int) -> None:
        """Remove a point and every keyframe's observation of it (a point culled for never
        being found again)."""
        if point_id not in self.points:
            raise MapError(f"cannot remove point {point_id}: not in the map")
        point = self._drop_point(point_id)
        for kf_id in point.observers:
            kf = self.keyframes[kf_id]
            kf.points.discard(point_id)
            kf.measurements.pop(point_id, None)
            kf.edited()

    def fuse(self, keep: int, drop: int) -> int:
        """Point ``drop`` is point ``keep`` seen again (a duplicate): every keyframe that
        observes ``drop`` observes ``keep`` instead, where it saw ``drop`` (one that sees
        both keeps its own view of ``keep``), and ``drop`` leaves the map. Returns how many
        observations moved to ``keep``."""
        return self.fuse_many([(keep, drop)])

    def fuse_many(self, pairs: Sequence[tuple[int, int]]) -> int:
        """:meth:`fuse` of each (keep, drop) of ``pairs`` — a point dropped once, and not
        kept by another pair — all checked before any is fused: the drops leave the map
        together and the kept points' observers are counted once (a keyframe restored into a
        shared place's map fuses a third of the hundreds of points it brings back). Returns
        the observations moved."""
        drops = [drop for _, drop in pairs]
        keeps = {keep for keep, _ in pairs}
        for keep, drop in pairs:
            if keep == drop or keep not in self.points or drop not in self.points:
                raise MapError(f"cannot fuse point {drop} into {keep}: the same point, or not "
                               "in the map")
        if len(set(drops)) != len(drops) or not keeps.isdisjoint(drops):
            raise MapError("a point fused away twice, or both kept and fused away")
        moved = 0
        for keep, drop in pairs:
            kept = self.points[keep]
            for kf_id in sorted(self.points[drop].observers):
                kf = self.keyframes[kf_id]
                kf.edited()
                seen = kf.measurements.pop(drop)
                kf.points.discard(drop)
                if keep not in kf.points:
                    kf.points.add(keep)
                    kf.measurements[keep] = seen
                    kept.observers.add(kf_id)
                    moved += 1
        self._drop_points(drops)
        self._count_observers(keeps)
        return moved

    def evict(self, kf_id: int) -> list[int]:
        """Remove a keyframe and its observations; returns the ids of the points that lost
        their last observer and were removed with it."""
        kf = self.keyframes.pop(kf_id, None)
        if kf is None:
            raise MapError(f"cannot evict keyframe {kf_id}: not in the map")
        seen = list(map(self.points.__getitem__, kf.points))
        observers = list(map(_OBSERVERS, seen))
        _run(map(set.discard, observers, repeat(kf_id)))
        left = np.fromiter(map(len, observers), dtype=np.int64, count=len(seen))
        orphans = [p.id for p, n in zip(seen, left.tolist(), strict=True) if not n]
        self._drop_points(orphans)
        self._count_observers_of([p for p, n in zip(seen, left.tolist(), strict=True) if n])
        return sorted(orphans)

    def _count_observers(self, point_ids: Collection[int]) -> None:
        """Write how many keyframes observe each of ``point_ids`` into the columns, after an
        edit of their observers (what the map update and the viewer's cloud send a point)."""
        self._count_observers_of(list(map(self.points.__getitem__, point_ids)))

    def _count_observers_of(self, points: list[MapPoint]) -> None:
        """:meth:`_count_observers` of the map's points ``points`` (each point's row and
        observer count read by C-level iteration)."""
        n = len(points)
        rows = np.fromiter(map(_ROW, points), dtype=np.int64, count=n)
        self.columns.observed[rows] = np.fromiter(map(len, map(_OBSERVERS, points)),
                                                  dtype=np.int64, count=n)

    # -- queries ---------------------------------------------------------------------------

    def keyframe_ids(self) -> list[int]:
        """Keyframe ids oldest first (ids grow with capture time)."""
        return sorted(self.keyframes)

    def point_array(self, kf_id: int) -> np.ndarray:
        """M_f of keyframe ``kf_id`` as an int64 array (unordered, read-only), for
        :func:`shared_counts`: the ids the keyframe keeps as an array until its observations
        change (the planner, the uncertainty and the restores read every keyframe's each
        slot)."""
        return self.keyframes[kf_id].observed()[0]

    def point_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point's id, ascending, and its row in :attr:`columns` (int64 arrays): the
        order the map update writes the points in."""
        return self.columns.by_id()

    def positions_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(n, 3)``: the positions of the map's points ``point_ids``, in their order."""
        return self.columns.positions_of(point_ids)

    def descriptors_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(n, 32)`` uint8: the descriptors of the map's points ``point_ids``, in their
        order."""
        return self.columns.descriptors_of(point_ids)

    def observer_counts(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(n,)`` int64: how many keyframes observe each of the map's points ``point_ids``."""
        counts: np.ndarray = self.columns.observed[self.columns.rows_of(point_ids)]
        return counts

    def set_positions(self, point_ids: Collection[int] | np.ndarray, positions: np.ndarray) -> None:
        """Move the map's points ``point_ids`` to ``positions`` ((n, 3), in their order): a
        loop's correction or a merge's alignment of thousands of points at once."""
        xyz = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if len(xyz) != len(point_ids):
            raise ValueError(f"{len(point_ids)} points but {len(xyz)} positions")
        self.columns.positions[self.columns.rows_of(point_ids)] = xyz

    def covisibility(self, ids: list[int] | None = None) -> np.ndarray:
        """w(f, f') = |M_f ∩ M_f'| for the keyframes ``ids`` (default: all, oldest first),
        zero diagonal — the weights the uncertainty and the policies take (read-only)."""
        return self.incidence(self.keyframe_ids() if ids is None else list(ids)).weights

    def incidence(self, ids: Sequence[int]) -> Incidence:
        """The point incidence and shared counts of the keyframes ``ids``, in their order.
        The last one made is kept while its keyframes' observations are unedited: the
        slot's end counts the map's weights for its uncertainty, and the next slot's plan
        reads the same map's (each ~3 ms on a 45-keyframe map, for each device)."""
        sets = [self.point_array(k) for k in ids]
        cached = self._incidence
        if cached is not None and cached.holds(ids, sets):
            return cached
        self._incidence = Incidence.of(ids, sets)
        return self._incidence

    def shared_points(self, point_ids: set[int]) -> np.ndarray:
        """Weights from a frame observing ``point_ids`` to every keyframe, oldest first."""
        return np.array([len(point_ids & self.keyframes[k].points)
                         for k in self.keyframe_ids()], dtype=np.float64)

    # -- checkpoint ------------------------------------------------------------------------

    def save(self, path: Path, **extra: Any) -> None:
        """Write the map (and ``extra`` arrays, e.g. the slot) atomically to ``path``
        (``Any``: numpy's stubs would match an array key to ``allow_pickle``)."""
        write_checkpoint(path, self.checkpoint_contents(**extra))

    def checkpoint_contents(self, **extra: Any) -> dict[str, np.ndarray]:
        """The arrays a checkpoint of the map holds, with ``extra``: the map's are copies,
        so that they may be written while the map changes (:func:`write_checkpoint`; the
        edge's writer copies the extras too)."""
        kf_ids = self.keyframe_ids()
        # every point's id and row read at C speed (the edge writes this every slot: a long
        # walk's map holds tens of thousands of points), sorted by id; the columns hold a row
        # for each of the map's points and its values, view counts included
        pt_ids, rows = self.columns.by_id()
        # every observation has its measurement (observe writes both, unobserve and evict
        # drop both), so the measurement dicts list the observations; the edge writes this
        # every slot, and each keyframe keeps its observations as arrays until they change
        observed = [self.keyframes[k].observed() for k in kf_ids]
        observers = np.repeat(np.array(kf_ids, dtype=np.int64), [len(o[0]) for o in observed])
        seen = np.concatenate([o[0] for o in observed] or [np.zeros(0, dtype=np.int64)])
        uvd = np.concatenate([o[1] for o in observed] or [np.zeros((0, 3))])
        # another device's keyframes' cameras (none in a map of one device's keyframes)
        other = [k for k in kf_ids if self.keyframes[k].intrinsics is not None]
        cameras = {} if not other else {
            "camera_keyframe_ids": np.array(other, dtype=np.int64),
            "camera_intrinsics": stacked_rows(
                [c for k in other if (c := self.keyframes[k].intrinsics) is not None],
                (3, 3), np.float64)}
        return dict(format=np.array(CHECKPOINT_FORMAT),
                    keyframe_ids=np.array(kf_ids, dtype=np.int64),
                    keyframe_poses=stacked_rows([self.keyframes[k].pose for k in kf_ids],
                                                (4, 4), np.float64),
                    point_ids=pt_ids,
                    point_positions=self.columns.positions[rows],
                    point_descriptors=self.columns.descriptors[rows],
                    observations=np.column_stack([observers, seen]).reshape(-1, 2),
                    measurements=uvd,
                    point_views=np.column_stack([self.columns.visible[rows],
                                                 self.columns.found[rows]]),
                    next_point_id=np.array(self.next_point_id), **cameras, **extra)

    @classmethod
    def load(cls, path: Path) -> tuple[KeyFrameMap, dict[str, np.ndarray]]:
        """The map saved at ``path`` and the extra arrays saved with it."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except NPZ_READ_ERRORS as exc:
            raise MapError(f"{path}: not a readable map checkpoint ({exc})") from None
        if str(data.pop("format", "")) != CHECKPOINT_FORMAT:
            raise MapError(f"{path}: not a {CHECKPOINT_FORMAT} checkpoint")
        m = cls()
        try:
            for k, pose in zip(data.pop("keyframe_ids"), data.pop("keyframe_poses"),
                               strict=True):
                m.add_keyframe(int(k), pose)
            m._put_points(data.pop("point_ids").astype(np.int64).tolist(),
                          data.pop("point_positions"), data.pop("point_descriptors"))
            observations, seen = data.pop("observations"), data.pop("measurements")
            if len(observations) != len(seen):
                raise ValueError(f"{len(observations)} observations, {len(seen)} measurements")
            # a keyframe's observations at once (the checkpoint lists them keyframe by
            # keyframe)
            order = np.argsort(observations[:, 0], kind="stable")
            observations, seen = observations[order], seen[order]
            cuts = np.flatnonzero(np.diff(observations[:, 0])) + 1
            for obs, uvd in zip(np.split(observations, cuts), np.split(seen, cuts),
                                strict=True):
                if len(obs):
                    m.observe_many(int(obs[0, 0]), obs[:, 1].tolist(), uvd[:, :2].tolist(),
                                   uvd[:, 2].tolist())
            m.next_point_id = int(data.pop("next_point_id"))
            for k, cam in zip(data.pop("camera_keyframe_ids", ()),
                              data.pop("camera_intrinsics", ()), strict=True):
                m.keyframes[int(k)].intrinsics = np.asarray(cam, dtype=np.float64).reshape(3, 3)
            # a checkpoint written before points counted their views: each starts afresh
            views = data.pop("point_views", None)
            if views is not None:
                rows = m.columns.rows_of(sorted(m.points))
                views = np.asarray(views, dtype=np.int64).reshape(-1, 2)
                if len(views) != len(rows):
                    raise ValueError(f"{len(views)} view counts for {len(rows)} points")
                m.columns.visible[rows], m.columns.found[rows] = views[:, 0], views[:, 1]
        except (KeyError, ValueError) as exc:
            raise MapError(f"{path}: inconsistent map checkpoint ({exc})") from None
        return m, data


def write_checkpoint(path: Path, arrays: Mapping[str, Any]) -> None:
    """``arrays`` (:meth:`KeyFrameMap.checkpoint_contents`) written to ``path`` whole or not
    at all (:func:`~twinslam.npz_files.write_npz`)."""
    write_npz(path, arrays)
