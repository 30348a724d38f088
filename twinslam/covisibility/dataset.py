"""Covisibility datasets: the per-frame map-point sets M_f of a real (or synthetic) sequence.

File format (``.npz``, written by :func:`save_covisibility`, read by :func:`load_covisibility`):

==================  ==========  =========================================================
key                 dtype       meaning
==================  ==========  =========================================================
``format``          str         ``"twinslam-covis-1"``
``point_offsets``   int64 n+1   frame i observes ``point_ids[point_offsets[i]:point_offsets[i+1]]``
``point_ids``       int64       concatenated, per frame sorted and unique
``stamps``          float64 n   capture times in seconds (optional)
``poses``           float64 n×7 estimated camera-to-world x y z qx qy qz qw (optional)
``source``          str         where the sets came from (sequence path, extractor version)
==================  ==========  =========================================================

Weights between frames are |M_f ∩ M_f'|, computed through a sparse frame × point incidence
matrix so a whole block of weights costs one sparse product.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from twinslam.kernel_cache import njit
from twinslam.npz_files import NPZ_READ_ERRORS

FORMAT = "twinslam-covis-1"
DENSE_LIMIT = 4000  #: up to this many frames all pairwise weights are precomputed (64 MB)


class CovisibilityError(ValueError):
    """A missing or malformed covisibility file."""


@dataclass
class CovisibilityDataset:
    """Per-frame point-id sets with fast weight queries."""

    point_offsets: np.ndarray
    point_ids: np.ndarray
    stamps: np.ndarray | None = None
    poses: np.ndarray | None = None
    source: str = ""

    def __post_init__(self) -> None:
        self.point_offsets = np.asarray(self.point_offsets, dtype=np.int64)
        self.point_ids = np.asarray(self.point_ids, dtype=np.int64)
        if self.point_offsets.ndim != 1 or self.point_offsets.size < 2:
            raise CovisibilityError("point_offsets must list at least one frame")
        if self.point_offsets[0] != 0 or self.point_offsets[-1] != self.point_ids.size \
                or np.any(np.diff(self.point_offsets) < 0):
            raise CovisibilityError("point_offsets do not index point_ids consistently")
        _, cols = np.unique(self.point_ids, return_inverse=True)
        #: per entry of point_ids, the point as a column 0..n_points-1 (for shared counts)
        self._cols = cols.astype(np.int64).ravel()
        self._marks = np.zeros(int(cols.max()) + 1 if cols.size else 1, dtype=np.bool_)
        rows = np.repeat(np.arange(self.n_frames), np.diff(self.point_offsets))
        self._incidence = sp.csr_matrix(
            (np.ones(rows.size, dtype=np.float64), (rows, cols)),
            shape=(self.n_frames, int(cols.max()) + 1 if cols.size else 1))
        self._incidence.sum_duplicates()
        self._incidence.data[:] = 1.0
        # Small datasets (the usual case: a few thousand frames) keep every weight in a dense
        # int32 matrix, so a slot's weight block is an index operation instead of a sparse product.
        self._dense: np.ndarray | None = None
        if self.n_frames <= DENSE_LIMIT:
            self._dense = (self._incidence @ self._incidence.T).toarray().astype(np.int32)

    def __reduce__(self) -> tuple[type[CovisibilityDataset], tuple[Any, ...]]:
        """Pickled as its fields alone (a sweep's worker rebuilds the incidence and weight
        matrices): a task carries the point sets, not up to 64 MB of derived weights."""
        return (CovisibilityDataset, (self.point_offsets, self.point_ids, self.stamps,
                                      self.poses, self.source))

    @classmethod
    def from_sets(cls, sets: list[np.ndarray] | list[set[int]], **kwargs: object
                  ) -> CovisibilityDataset:
        arrays = [np.unique(np.fromiter(s, dtype=np.int64)) if isinstance(s, set)
                  else np.unique(np.asarray(s, dtype=np.int64)) for s in sets]
        offsets = np.concatenate([[0], np.cumsum([a.size for a in arrays])])
        ids = np.concatenate(arrays) if arrays else np.zeros(0, dtype=np.int64)
        return cls(offsets, ids, **kwargs)  # type: ignore[arg-type]

    @property
    def dense(self) -> bool:
        """Whether all pairwise weights are precomputed (a weight block is then a gather)."""
        return self._dense is not None

    @property
    def dense_weights(self) -> np.ndarray:
        """The n×n int32 matrix of all pairwise weights (only when :attr:`dense`)."""
        if self._dense is None:
            raise ValueError(f"{self.n_frames} frames: weights are not kept dense "
                             f"(limit {DENSE_LIMIT})")
        return self._dense

    @property
    def n_frames(self) -> int:
        return int(self.point_offsets.size - 1)

    @property
    def n_points(self) -> int:
        """Distinct points over all frames (columns 0 … n_points - 1)."""
        return int(self._marks.size)

    @property
    def point_columns(self) -> np.ndarray:
        """Per entry of ``point_ids``, its point as a column 0 … n_points - 1."""
        return self._cols

    def points(self, frame: int) -> np.ndarray:
        return self.point_ids[self.point_offsets[frame]:self.point_offsets[frame + 1]]

    def stretch(self, start: int, end: int) -> CovisibilityDataset:
        """Frames ``start`` … ``end - 1`` as a dataset of their own: a part of the trajectory
        to train on while another part is held out for evaluation."""
        if not 0 <= start < end <= self.n_frames or end - start < 2:
            raise CovisibilityError(f"frames {start}:{end} are not a stretch of >= 2 of the "
                                    f"{self.n_frames} frames")
        lo, hi = self.point_offsets[start], self.point_offsets[end]
        return CovisibilityDataset(
            self.point_offsets[start:end + 1] - lo, self.point_ids[lo:hi],
            None if self.stamps is None else self.stamps[start:end],
            None if self.poses is None else self.poses[start:end],
            f"{self.source} [frames {start}:{end}]")

    def weights(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """|M_r ∩ M_c| for every (r, c), as a dense float64 block."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        if rows.size == 0 or cols.size == 0:
            return np.zeros((rows.size, cols.size))
        if self._dense is not None:
            return _gather(self._dense, rows, cols)
        block = self._incidence[rows] @ self._incidence[cols].T
        return np.asarray(block.toarray())


    def shared_points(self, map_rows: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """|M_r ∩ ∪_{m ∈ map_rows} M_m| for every r of ``rows``: the map points a frame
        could match in a map of those frames, each counted once however many of the map's
        frames see it (the device matches a point once)."""
        return _shared_points(self.point_offsets, self._cols, self._marks,
                              np.asarray(map_rows, dtype=np.int64),
                              np.asarray(rows, dtype=np.int64))


def save_covisibility(path: Path, data: CovisibilityDataset) -> None:
    """Write ``data`` to ``path`` whole or not at all: into a file beside it, renamed over
    ``path`` once written (a process killed while writing leaves no cut-off file that a cache
    would take for a whole one)."""
    path = Path(path)
    extra: dict[str, Any] = {}       # Any: numpy's stubs would match a key to allow_pickle
    if data.stamps is not None:
        extra["stamps"] = np.asarray(data.stamps, dtype=np.float64)
    if data.poses is not None:
        extra["poses"] = np.asarray(data.poses, dtype=np.float64)
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with partial.open("wb") as f:
            np.savez_compressed(f, format=np.array(FORMAT), point_offsets=data.point_offsets,
                                point_ids=data.point_ids, source=np.array(data.source), **extra)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def load_covisibility(path: Path) -> CovisibilityDataset:
    path = Path(path)
    if not path.is_file():
        raise CovisibilityError(f"covisibility file {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as npz:
            fmt = str(npz["format"]) if "format" in npz else ""
            if fmt != FORMAT:
                raise CovisibilityError(f"{path}: format {fmt!r}, expected {FORMAT!r}")
            return CovisibilityDataset(
                npz["point_offsets"], npz["point_ids"],
                stamps=npz["stamps"] if "stamps" in npz else None,
                poses=npz["poses"] if "poses" in npz else None,
                source=str(npz["source"]) if "source" in npz else "")
    except NPZ_READ_ERRORS as exc:
        if isinstance(exc, CovisibilityError):
            raise
        raise CovisibilityError(f"{path}: not a readable covisibility file ({exc})") from None


@njit(cache=True)
def _gather(dense: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """dense[rows][:, cols] as float64 in one pass (numpy's 2-D fancy indexing costs ~20 µs
    of set-up for a 60×45 block, more than the copy; the simulator asks for several per slot)."""
    out = np.empty((rows.size, cols.size))
    for i in range(rows.size):
        for j in range(cols.size):
            out[i, j] = dense[rows[i], cols[j]]
    return out


@njit(cache=True)
def _shared_points(offsets: np.ndarray, cols: np.ndarray, marks: np.ndarray,
                   map_rows: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Mark the map's points, count each row's marked points, clear the marks (``marks`` is
    all False before and after: one buffer per dataset, no allocation per slot)."""
    for m in map_rows:
        for j in range(offsets[m], offsets[m + 1]):
            marks[cols[j]] = True
    out = np.zeros(rows.size, dtype=np.int64)
    for i in range(rows.size):
        r = rows[i]
        for j in range(offsets[r], offsets[r + 1]):
            if marks[cols[j]]:
                out[i] += 1
    for m in map_rows:
        for j in range(offsets[m], offsets[m + 1]):
            marks[cols[j]] = False
    return out
