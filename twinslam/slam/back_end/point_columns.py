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
beyond :data:`DENSE_IDS` (another device's points, tagged in their high bits) are held in an
id-sorted array beside (:class:`SortedRows`): in a map of a shared place most points are
another device's, and finding them id by id in the dict was a third of what such a map cost
the edge over an unshared one (the checkpoint, the restores' view scores).
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from twinslam.slam.sorted_ids import find_sorted

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
        self._beyond = SortedRows()            #: the other ids' rows (another device's)
        self._free: list[int] = []             #: rows points left, taken first
        self._used = 0                         #: rows ever handed out
        #: every point added, in the order they came (id, row), those that left among them:
        #: entry i is held while its row's entry is i (:meth:`ids_and_rows`)
        self._came_ids = np.zeros(max(1, capacity), dtype=np.int64)
        self._came_rows = np.zeros(max(1, capacity), dtype=np.int64)
        self._came = 0                         #: entries written
        self._entry_of_row = np.full(max(1, capacity), -1, dtype=np.int64)

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
        self._note_came(ids, at)
        dense = (ids >= 0) & (ids < DENSE_IDS)
        if not dense.all():
            self._beyond.add(ids[~dense], at[~dense])
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
        self._entry_of_row[r] = -1
        if 0 <= point_id < len(self._row_by_id):
            self._row_by_id[point_id] = -1
        if not 0 <= point_id < DENSE_IDS:
            self._beyond.remove(point_id)
        return r

    def rows_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """The rows of ``point_ids`` (in their order) as an int64 array; KeyError for an id
        the columns do not hold. An integer array is read at once (:meth:`rows_or_none`);
        anything else (a list, a set) id by id."""
        if isinstance(point_ids, np.ndarray) and point_ids.dtype.kind in "iu":
            rows = self.rows_or_none(point_ids)
            missing = np.flatnonzero(rows < 0)
            if len(missing):
                raise KeyError(int(point_ids.ravel()[missing[0]]))
            return rows.reshape(point_ids.shape)
        return np.fromiter(map(self.row.__getitem__, point_ids), dtype=np.int64,
                           count=len(point_ids))

    def rows_or_none(self, point_ids: np.ndarray) -> np.ndarray:
        """Each of ``point_ids``' row (an integer array, flattened), -1 where it has none: the
        map's own ids read from the rows by id at once, another device's found in its sorted
        rows (:class:`SortedRows`) at once."""
        ids = np.asarray(point_ids, dtype=np.int64).ravel()
        dense = (ids >= 0) & (ids < self._dense_bound())
        rows = np.empty(len(ids), dtype=np.int64)
        rows[dense] = self._row_by_id[ids[dense]]
        if not dense.all():
            rows[~dense] = self._beyond.find(ids[~dense])
        return rows

    def holds(self, point_ids: np.ndarray) -> np.ndarray:
        """Whether each of ``point_ids`` (an integer array) has a row."""
        return self.rows_or_none(point_ids) >= 0

    def _dense_bound(self) -> int:
        """Ids below it have their row (or -1) in the rows by id; the others are in the sorted
        rows of another device's ids (the rows by id may have grown past ``DENSE_IDS``)."""
        return min(len(self._row_by_id), DENSE_IDS)

    def ids_and_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point's id and row (int64 arrays, in the order the points came, as the dict
        of rows lists them): read off the entries of the points that came, those still held,
        not out of the dict (a map of a shared place holds tens of thousands of points, and
        a restored keyframe's fusion reads them all)."""
        n = self._came
        held = self._entry_of_row[self._came_rows[:n]] == np.arange(n)
        return self._came_ids[:n][held], self._came_rows[:n][held]

    def _note_came(self, ids: np.ndarray, rows: np.ndarray) -> None:
        """New points' ids and rows entered after those that came before; the entries of
        points that left dropped once they are half of them."""
        if self._came + len(ids) > len(self._came_ids):
            if 2 * len(self.row) <= self._came:           # half of them left: drop those
                old_ids, old_rows = self.ids_and_rows()
                self._came = len(old_ids)
                self._came_ids[:self._came], self._came_rows[:self._came] = old_ids, old_rows
                self._entry_of_row[old_rows] = np.arange(self._came)
            size = len(self._came_ids)
            while self._came + len(ids) > size:
                size *= 2
            self._came_ids = np.resize(self._came_ids, size)
            self._came_rows = np.resize(self._came_rows, size)
        entries = np.arange(self._came, self._came + len(ids))
        self._came_ids[entries], self._came_rows[entries] = ids, rows
        self._entry_of_row[rows] = entries
        self._came += len(ids)

    def by_id(self) -> tuple[np.ndarray, np.ndarray]:
        """Every point's id, ascending, and its row (int64 arrays): the order the checkpoint
        and the map update write the points in — the map's own read off the rows by id
        (ascending already), another device's sorted apart."""
        own = np.flatnonzero(self._row_by_id >= 0)
        rows = self._row_by_id[own].astype(np.int64)
        if not len(self._beyond):
            return own.astype(np.int64), rows
        others, their_rows = self._beyond.items()
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
        self._entry_of_row = np.concatenate([self._entry_of_row,
                                             np.full(n, -1, dtype=np.int64)])
        self.positions = np.concatenate([self.positions, np.zeros_like(self.positions)])
        self.descriptors = np.concatenate([self.descriptors, np.zeros_like(self.descriptors)])
        self.observed = np.concatenate([self.observed, np.zeros_like(self.observed)])
        self.visible = np.concatenate([self.visible, np.zeros_like(self.visible)])
        self.found = np.concatenate([self.found, np.zeros_like(self.found)])
        assert len(self.positions) == 2 * n


class SortedRows:
    """The rows of the ids the rows by id do not hold (another device's points, tagged in
    their high bits), in two arrays sorted by id: the rows of thousands of ids found in one
    sorted search, every id in order read off as it is. An id that leaves is struck out
    (row -1) with the others that left since, at the next question: a map drops the points
    of an evicted keyframe one by one; the struck-out entries are dropped once they are half
    the arrays."""

    def __init__(self) -> None:
        self._ids = np.zeros(0, dtype=np.int64)        #: ascending, without repeats
        self._rows = np.zeros(0, dtype=np.int64)       #: -1: left
        self._live = 0
        self._left: list[int] = []                     #: ids that left, not struck out yet

    def __len__(self) -> int:
        return self._live

    def add(self, ids: np.ndarray, rows: np.ndarray) -> None:
        """Ids none of which is held, with their rows."""
        self._strike_out()
        order = np.argsort(ids, kind="stable")
        ids = np.asarray(ids, dtype=np.int64)[order]
        rows = np.asarray(rows, dtype=np.int64)[order]
        at, back = find_sorted(self._ids, ids)        # back: struck out before, come again
        self._rows[at[back]] = rows[back]
        self._ids = np.insert(self._ids, at[~back], ids[~back])
        self._rows = np.insert(self._rows, at[~back], rows[~back])
        self._live += len(ids)

    def remove(self, point_id: int) -> None:
        """Id ``point_id`` (held) leaves."""
        self._left.append(point_id)
        self._live -= 1

    def find(self, ids: np.ndarray) -> np.ndarray:
        """Each id's row, -1 where it has none."""
        self._strike_out()
        at, found = find_sorted(self._ids, ids)
        rows = np.full(len(ids), -1, dtype=np.int64)
        rows[found] = self._rows[at[found]]
        return rows

    def items(self) -> tuple[np.ndarray, np.ndarray]:
        """Every id held, ascending, and its row."""
        self._strike_out()
        held = self._rows >= 0
        return self._ids[held], self._rows[held]

    def _strike_out(self) -> None:
        if not self._left:
            return
        at, found = find_sorted(self._ids, np.array(self._left, dtype=np.int64))
        self._rows[at[found]] = -1
        self._left = []
        if 2 * (len(self._ids) - self._live) > len(self._ids):
            held = self._rows >= 0
            self._ids, self._rows = self._ids[held], self._rows[held]
