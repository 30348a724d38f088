"""How many of a map's points each frame sees, kept up to date as keyframes come and go.

The device's rule of a lost frame (``twinslam/slot_protocol/lost_frame_rule.py``) counts, for each
of a slot's frames, the points it shares with the union of the map's keyframes — each point once.
Marking the union afresh costs every keyframe's ~1 000 point ids twice a slot (mark, then
clear), about half the simulator's time under that rule; consecutive maps differ by a few
uploads and evictions, so :class:`MapPointCounts` keeps, per point, how many of the map's
keyframes see it and moves it by the difference only.
"""

from __future__ import annotations

import numpy as np

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.kernel_cache import njit


class MapPointCounts:
    """Per point of ``dataset``, the number of the current map's keyframes that see it."""

    def __init__(self, dataset: CovisibilityDataset) -> None:
        self._offsets = dataset.point_offsets
        self._cols = dataset.point_columns
        self._counts = np.zeros(dataset.n_points, dtype=np.int32)
        self._map = np.zeros(0, dtype=np.int64)          #: sorted dataset rows (repeats kept)

    def shared(self, map_rows: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """|M_r ∩ ∪_{m ∈ map_rows} M_m| for every r of ``rows`` (the dataset's
        :meth:`~CovisibilityDataset.shared_points`), after moving the counts to ``map_rows``
        (a row listed twice, e.g. one place seen on the way out and back, counts twice)."""
        new = np.sort(np.asarray(map_rows, dtype=np.int64))
        _move(self._offsets, self._cols, self._counts, self._map, new)
        self._map = new
        return _hits(self._offsets, self._cols, self._counts, np.asarray(rows, dtype=np.int64))


    def reaching(self, map_rows: np.ndarray, rows: np.ndarray, need: int) -> np.ndarray:
        """Whether each of ``rows`` shares at least ``need`` points with the map of
        ``map_rows`` (:meth:`shared` >= need): a frame stops being counted once it gets
        there, a few dozen reads instead of its ~1 000 — the device's rule asks no more."""
        new = np.sort(np.asarray(map_rows, dtype=np.int64))
        _move(self._offsets, self._cols, self._counts, self._map, new)
        self._map = new
        return _reaching(self._offsets, self._cols, self._counts,
                         np.asarray(rows, dtype=np.int64), int(need))


@njit(cache=True)
def _add(offsets: np.ndarray, cols: np.ndarray, counts: np.ndarray, row: int,
         delta: int) -> None:
    for j in range(offsets[row], offsets[row + 1]):
        counts[cols[j]] += delta


@njit(cache=True)
def _move(offsets: np.ndarray, cols: np.ndarray, counts: np.ndarray, old: np.ndarray,
          new: np.ndarray) -> None:
    """Counts of the map ``old`` → of the map ``new`` (both sorted): a merge of the two
    multisets, touching only the rows in one but not the other."""
    i = j = 0
    while i < old.size or j < new.size:
        if j == new.size or (i < old.size and old[i] < new[j]):
            _add(offsets, cols, counts, old[i], -1)
            i += 1
        elif i == old.size or new[j] < old[i]:
            _add(offsets, cols, counts, new[j], 1)
            j += 1
        else:
            i += 1
            j += 1


@njit(cache=True)
def _hits(offsets: np.ndarray, cols: np.ndarray, counts: np.ndarray,
          rows: np.ndarray) -> np.ndarray:
    out = np.zeros(rows.size, dtype=np.int64)
    for i in range(rows.size):
        r = rows[i]
        for j in range(offsets[r], offsets[r + 1]):
            if counts[cols[j]] > 0:
                out[i] += 1
    return out


@njit(cache=True)
def _reaching(offsets: np.ndarray, cols: np.ndarray, counts: np.ndarray, rows: np.ndarray,
              need: int) -> np.ndarray:
    out = np.zeros(rows.size, dtype=np.bool_)
    for i in range(rows.size):
        r = rows[i]
        n = 0
        for j in range(offsets[r], offsets[r + 1]):
            if counts[cols[j]] > 0:
                n += 1
                if n >= need:
                    out[i] = True
                    break
    return out
