"""The device's local map: the map points it tracks against — world position, ORB descriptor,
the direction it was seen from, when each was last seen.

Stored as growing column arrays (not one object per point) because tracking projects and
matches all candidate points of a frame at once.
"""

from __future__ import annotations

import numpy as np

from msg_schemas.validation import ORB_DESCRIPTOR_BYTES


class LocalMap:
    """The tracker's map points as an append-only store; a point's id is its row (the edge's
    map update replaces the whole store, :meth:`DeviceTrackerCore.apply_map_update`). Each
    point knows whether it came in the edge's map (``from_edge``) or the device made it."""

    def __init__(self, capacity: int = 4096) -> None:
        self._pos = np.empty((capacity, 3))
        self._desc = np.empty((capacity, ORB_DESCRIPTOR_BYTES), dtype=np.uint8)
        self._last_seen = np.empty(capacity, dtype=np.int64)
        self._seen_count = np.empty(capacity, dtype=np.int64)
        self._active = np.empty(capacity, dtype=np.bool_)
        self._from_edge = np.empty(capacity, dtype=np.bool_)
        self._views = np.empty((capacity, 3))
        self._n = 0

    def __len__(self) -> int:
        return self._n

    @property
    def positions(self) -> np.ndarray:
        return self._pos[:self._n]

    @property
    def descriptors(self) -> np.ndarray:
        return self._desc[:self._n]

    @property
    def last_seen(self) -> np.ndarray:
        return self._last_seen[:self._n]

    @property
    def seen_count(self) -> np.ndarray:
        return self._seen_count[:self._n]

    @property
    def active(self) -> np.ndarray:
        """False for culled points: kept (ids stay valid) but no longer searched for."""
        return self._active[:self._n]

    @property
    def from_edge(self) -> np.ndarray:
        """True for a point of the edge's map update, False for one the device made since."""
        return self._from_edge[:self._n]

    @property
    def views(self) -> np.ndarray:
        """The unit direction each point was seen from (the mean over the keyframes that
        observed it, :mod:`twinslam.slam.viewing_directions`); NaN where none is known."""
        return self._views[:self._n]

    def cull(self, ids: np.ndarray) -> None:
        self._active[ids] = False

    def move(self, correction: np.ndarray) -> None:
        """Every point moved by the rigid ``correction`` (4×4): the frame they are in was
        corrected (a loop closed at the edge)."""
        c = np.asarray(correction, dtype=np.float64)
        self.positions[:] = self.positions @ c[:3, :3].T + c[:3, 3]
        self.views[:] = self.views @ c[:3, :3].T

    def add(self, positions: np.ndarray, descriptors: np.ndarray, frame: int,
            from_edge: bool = False, views: np.ndarray | None = None) -> np.ndarray:
        """Append points first seen in ``frame`` (``from_edge``: the edge's map's, else the
        device's own), seen from ``views`` (unit rows; None: unknown); returns their new
        ids."""
        k = positions.shape[0]
        if self._n + k > self._pos.shape[0]:
            cap = max(2 * self._pos.shape[0], self._n + k)
            self._pos = _grow(self._pos, cap)
            self._desc = _grow(self._desc, cap)
            self._last_seen = _grow(self._last_seen, cap)
            self._seen_count = _grow(self._seen_count, cap)
            self._active = _grow(self._active, cap)
            self._from_edge = _grow(self._from_edge, cap)
            self._views = _grow(self._views, cap)
        ids = np.arange(self._n, self._n + k)
        self._pos[ids] = positions
        self._desc[ids] = descriptors
        self._last_seen[ids] = frame
        self._seen_count[ids] = 1
        self._active[ids] = True
        self._from_edge[ids] = from_edge
        self._views[ids] = np.nan if views is None else views
        self._n += k
        return ids

    def take(self, rows: np.ndarray) -> LocalMap:
        """A new map of the points ``rows`` (ascending), renumbered 0..len(rows) - 1, with
        their positions, descriptors, viewing directions, sightings, activity and origin."""
        out = LocalMap(max(int(rows.size), 16))
        new = out.add(self.positions[rows], self.descriptors[rows], 0,
                      views=self.views[rows])
        out.last_seen[new] = self.last_seen[rows]
        out.seen_count[new] = self.seen_count[rows]
        out.active[new] = self.active[rows]
        out.from_edge[new] = self.from_edge[rows]
        return out

    def mark_seen(self, ids: np.ndarray, frame: int) -> None:
        self._last_seen[ids] = frame
        self._seen_count[ids] += 1


def _grow(a: np.ndarray, capacity: int) -> np.ndarray:
    out = np.empty((capacity, *a.shape[1:]), dtype=a.dtype)
    out[:a.shape[0]] = a
    return out
