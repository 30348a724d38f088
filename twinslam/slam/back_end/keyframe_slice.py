"""The keyframes one device holds of its place's map: what its map update carries, what its
map uncertainty u(G) and its policy's υ are scored on, what C_k evicts from.

The paper's map management bounds what one device synchronises with the edge — at most V_max
keyframes — not what the edge keeps of a place. One map a place (docs/architecture.md, "Devices
in one place") keeps every keyframe its devices uploaded once, in one :class:`KeyFrameMap`, and
gives each device a *slice* of it: the keyframes that device holds. Two devices of a place hold
many keyframes alike (the ones of the ground both walk), so a slice is kept as the place's map
less the keyframes its device does *not* hold (:meth:`KeyFrameSlice.set_apart`): a place of
one device — every map until a merge joins stores — sets none apart, and its slice is its map,
read at no cost and in the map's own order (the readers' figures stay what they were, to the
digit).

A slice answers what the device's readers asked of the map: its keyframes, the points they
see, their covisibility and point incidence (the place's map keeps the last one made, so
a slice's planner and its slot's end share it as the map's did), the map update's point rows.
It edits nothing: keyframes enter and leave the place's map through its back end, which sets
apart and takes in a slice's keyframes as its device evicts and restores them.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence

import numpy as np

from twinslam.slam.back_end.keyframe_map import Incidence, KeyFrame, KeyFrameMap, MapPoint
from twinslam.slam.back_end.point_columns import PointColumns


class KeyFrameSlice:
    """The keyframes of ``place`` one device holds: all of them but those set apart."""

    def __init__(self, place: KeyFrameMap) -> None:
        self.place = place
        #: keyframes of the place this device does not hold (one the place drops is
        #: forgotten: :meth:`left_place`)
        self._apart: set[int] = set()

    # -- which keyframes -------------------------------------------------------------------

    def set_apart(self, keyframes: Iterable[int]) -> None:
        """The device no longer holds ``keyframes`` of its place (another device's slice
        may, and the place's map keeps them while one does)."""
        self._apart.update(keyframes)
        self._apart.intersection_update(self.place.keyframes)

    def take_in(self, keyframes: Iterable[int]) -> None:
        """The device holds ``keyframes`` of its place again (a restore brought them)."""
        self._apart.difference_update(keyframes)
        self._apart.intersection_update(self.place.keyframes)

    def left_place(self, keyframes: Iterable[int]) -> None:
        """``keyframes`` left the place's map (archived, forgotten): none of them stays set
        apart, so a keyframe that enters the place again under its id is held."""
        self._apart.difference_update(keyframes)

    @property
    def apart(self) -> frozenset[int]:
        """The place's keyframes this device does not hold."""
        return frozenset(k for k in self._apart if k in self.place.keyframes)

    def holds(self, kf_id: int) -> bool:
        """Whether keyframe ``kf_id`` is in the place's map and the device holds it."""
        return kf_id in self.place.keyframes and kf_id not in self._apart

    @property
    def whole(self) -> bool:
        """Whether the slice holds every keyframe of its place (a place of one device)."""
        return self._apart.isdisjoint(self.place.keyframes)

    @property
    def keyframes(self) -> Mapping[int, KeyFrame]:
        """The keyframes the device holds by id, in the place map's order (its own dict
        where the slice is whole)."""
        if self.whole:
            return self.place.keyframes
        return {k: kf for k, kf in self.place.keyframes.items() if k not in self._apart}

    def keyframe_ids(self) -> list[int]:
        """The held keyframes' ids, oldest first (ids grow with capture time)."""
        return sorted(self.keyframes)

    # -- what they see ---------------------------------------------------------------------

    def point_ids(self) -> np.ndarray:
        """The ids of the points the held keyframes see (int64, ascending: the order the map
        update writes them in)."""
        return self.point_rows()[0]

    def point_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The held keyframes' points' ids (ascending) and their rows in the place's columns
        (int64 arrays)."""
        if self.whole:
            return self.place.point_rows()
        ids = self.incidence(self.keyframe_ids()).points
        return ids, self.place.columns.rows_of(ids)

    @property
    def points(self) -> Mapping[int, MapPoint]:
        """The points the held keyframes see, by id (the place's own dict where whole)."""
        if self.whole:
            return self.place.points
        return {p: self.place.points[p] for p in self.point_ids().tolist()}

    @property
    def columns(self) -> PointColumns:
        """The place's point columns (a slice's points are rows of them: :meth:`point_rows`)."""
        return self.place.columns

    def point_array(self, kf_id: int) -> np.ndarray:
        """M_f of keyframe ``kf_id`` (:meth:`KeyFrameMap.point_array`)."""
        return self.place.point_array(kf_id)

    def positions_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(n, 3)``: the positions of the place's points ``point_ids``."""
        return self.place.positions_of(point_ids)

    def descriptors_of(self, point_ids: Collection[int] | np.ndarray) -> np.ndarray:
        """``(n, 32)`` uint8: the descriptors of the place's points ``point_ids``."""
        return self.place.descriptors_of(point_ids)

    def incidence(self, ids: Sequence[int]) -> Incidence:
        """The point incidence of keyframes ``ids`` (the place's map keeps the last made)."""
        return self.place.incidence(ids)

    def covisibility(self, ids: list[int] | None = None) -> np.ndarray:
        """w(f, f') = |M_f ∩ M_f'| over the held keyframes (default) or ``ids``, zero
        diagonal: the weights u(G) and the policies take."""
        return self.incidence(self.keyframe_ids() if ids is None else list(ids)).weights


#: what a device's readers (its map update, its planner, its restores) read: a map, or one
#: device's slice of its place's map
MapView = KeyFrameMap | KeyFrameSlice

__all__ = ["KeyFrameSlice", "MapView"]
