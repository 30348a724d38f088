"""The map points' positions and descriptors as two arrays, one row a point.

Every slot, for every device, the edge reads the positions and descriptors of thousands of
map points at once: the checkpoint, the map update, the loop closer's snapshot of the map,
integration's local map and its search for a feature's duplicate, the viewer's cloud. Held
as one small array a point, each such read was a Python step a point (``np.concatenate``
over a list of arrays: ~10 ms a slot on a 20 000-point map, in several places). Held as rows
of two arrays, any set of points is one fancy index.

A point keeps its row for as long as it is in the map; a row freed by a point that left is
taken by the next new point, and the arrays double when every row is taken, so neither a
point's row nor the cost of adding one depends on the map's history.

A map names its own points 1, 2, 3, … (``KeyFrameMap.next_point_id``), so their rows are also
held in an array indexed by id: the ids of thousands of points, given as an array, find their
rows in one gather instead of a dict lookup each (10 000 ids: 0.03 ms against 0.7). Ids
beyond :data:`DENSE_IDS` (another device's points, tagged in their high bits) are found by
the dict alone.
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

#: bytes of an ORB descriptor
DESCRIPTOR_BYTES = 32
#: ids below this have their row in the array by id too (4 bytes an id ever made)
DENSE_IDS = 1 << 26


class PointColumns:
    """Positions ((rows, 3) float64, map frame), descriptors ((rows, 32) uint8), how many
    keyframes observe each ((rows,) int64: kept by the map as it links observations) and each
    point's view counts (``visible``, ``found``: (rows,) int64, what point culling judges a
    point by; a new point starts at one of each) of the points a map holds, with each point's
    row by id."""

    def __init__(self, capacity: int = 1024) -> None:
        self.positions = np.zeros((max(1, capacity), 3), dtype=np.float64)
        self.descriptors = np.zeros((max(1, capacity), DESCRIPTOR_BYTES), dtype=np.uint8)
        self.observed = np.zeros(max(1, capacity), dtype=np.int64)
        self.visible = np.zeros(max(1, capacity), dtype=np.int64)
        self.found = np.zeros(max(1, capacity), dtype=np.int64)
        self.row: dict[int, int] = {}          #: point id → its row
        #: row by id for ids below DENSE_IDS (-1: no such point): the dict's rows, gathered
        self._row_by_id = np.full(max(1, capacity), -1, dtype=np.int32)
        self._beyond: dict[int, int] = {}      #: the other ids' rows (another device's)
        self._free: list[int] = []             #: rows points left, taken first
        self._used = 0                         #: rows ever handed out

    def __len__(self) -> int:
        return len(self.row)

    def add_many(self, point_ids: list[int], positions: np.ndarray, descriptors: np.ndarray
                 ) -> np.ndarray:
        """Rows for new points (a keyframe's integration makes hundreds at once, a restore
        brings hundreds back), written with their positions and descriptors; returns them.
        Rows points left are taken first (the last freed first), then rows never used."""
        if len(set(point_ids)) != len(point_ids) or any(p in self.row for p in point_ids):
            raise KeyError("a point has a row already, or is named twice")
        n = len(point_ids)
        reused = min(n, len(self._free))
        rows = [self._free.pop() for _ in range(reused)]
        while self._used + n - reused > len(self.positions):
            self._grow()
        rows.extend(range(self._used, self._used + n - reused))
        self._used += n - reused
        at = np.asarray(rows, dtype=np.int64)
        self.positions[at] = np.asarray(positions, dtype=np.float64).reshape(n, 3)
        self.descriptors[at] = np.asarray(descriptors, dtype=np.uint8).reshape(n, DESCRIPTOR_BYTES)
        self.observed[at] = 0
        self.visible[at] = self.found[at] = 1
        self.row.update(zip(point_ids, rows, strict=True))
        ids = np.asarray(point_ids, dtype=np.int64)
        dense = (ids >= 0) & (ids < DENSE_IDS)
        if not dense.all():
            self._beyond.update(zip(ids[~dense].tolist(), at[~dense].tolist(), strict=True))
        if dense.any():
            while ids[dense].max() >= len(self._row_by_id):
                self._row_by_id = np.concatenate(
                    [self._row_by_id, np.full(len(self._row_by_id), -1, dtype=np.int32)])
            self._row_by_id[ids[dense]] = at[dense]
        return at

    def remove(self, point_id: int) -> int:
        """Free the row of a point that left the map; returns the row it had."""
        r = self.row.pop(point_id)
        self._free.append(r)
        if 0 <= point_id < len(self._row_by_id):
            self._row_by_id[point_id] = -1
        self._beyond.pop(point_id, None)
        return r

    def rows_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """The rows of ``point_ids`` (in their order) as an int64 array; KeyError for an id
        the columns do not hold. In an integer array the map's own ids are read from the rows
        by id at once, another device's (its copies' points, in a map of a shared place) id
        by id; anything else (a list, a set) id by id."""
        if isinstance(point_ids, np.ndarray) and point_ids.dtype.kind in "iu":
            ids = point_ids.astype(np.int64, copy=False).ravel()
            dense = (ids >= 0) & (ids < self._dense_bound())
            rows = np.empty(len(ids), dtype=np.int64)
            rows[dense] = self._row_by_id[ids[dense]]
            missing = np.flatnonzero(dense & (rows < 0))
            if len(missing):
                raise KeyError(int(ids[missing[0]]))
            if not dense.all():
                rows[~dense] = np.fromiter(map(self._beyond.__getitem__, ids[~dense].tolist()),
                                           dtype=np.int64, count=int((~dense).sum()))
            return rows.reshape(point_ids.shape)
        return np.fromiter(map(self.row.__getitem__, point_ids), dtype=np.int64,
                           count=len(point_ids))

    def holds(self, point_ids: np.ndarray) -> np.ndarray:
        """Whether each of ``point_ids`` (an integer array) has a row: the map's own ids read
        from the rows by id at once, another device's by the dict."""
        ids = np.asarray(point_ids, dtype=np.int64).ravel()
        dense = (ids >= 0) & (ids < self._dense_bound())
        held = np.zeros(len(ids), dtype=bool)
        held[dense] = self._row_by_id[ids[dense]] >= 0
        if not dense.all():
            held[~dense] = np.fromiter(map(self._beyond.__contains__, ids[~dense].tolist()),
                                       dtype=bool, count=int((~dense).sum()))
        return held

    def _dense_bound(self) -> int:
        """Ids below it have their row (or -1) in the rows by id; the others are in the dict
        of another device's ids (the rows by id may have grown past ``DENSE_IDS``)."""
        return min(len(self._row_by_id), DENSE_IDS)

    def ids_and_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point's id and row (int64 arrays, in the order the points came): all the
        map's points read at C speed, not a lookup a point."""
        n = len(self.row)
        return (np.fromiter(self.row.keys(), dtype=np.int64, count=n),
                np.fromiter(self.row.values(), dtype=np.int64, count=n))

    def by_id(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point's id, ascending, and its row (int64 arrays): the order the checkpoint
        and the map update write the points in — the map's own read off the rows by id
        (ascending already), another device's sorted apart."""
        own = np.flatnonzero(self._row_by_id >= 0)
        rows = self._row_by_id[own].astype(np.int64)
        if not self._beyond:
            return own.astype(np.int64), rows
        others = np.array(sorted(self._beyond), dtype=np.int64)
        their_rows = np.fromiter(map(self._beyond.__getitem__, others.tolist()),
                                 dtype=np.int64, count=len(others))
        below = others < 0
        return (np.concatenate([others[below], own, others[~below]]),
                np.concatenate([their_rows[below], rows, their_rows[~below]]))

    def positions_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(len(point_ids), 3)``: the points' positions, a copy."""
        out: np.ndarray = self.positions[self.rows_of(point_ids)]
        return out

    def descriptors_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(len(point_ids), 32)``: the points' descriptors, a copy."""
        out: np.ndarray = self.descriptors[self.rows_of(point_ids)]
        return out

    def _grow(self) -> None:
        n = len(self.positions)
        self.positions = np.concatenate([self.positions, np.zeros_like(self.positions)])
        self.descriptors = np.concatenate([self.descriptors, np.zeros_like(self.descriptors)])
        self.observed = np.concatenate([self.observed, np.zeros_like(self.observed)])
        self.visible = np.concatenate([self.visible, np.zeros_like(self.visible)])
        self.found = np.concatenate([self.found, np.zeros_like(self.found)])
        assert len(self.positions) == 2 * n
