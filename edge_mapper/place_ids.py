"""A joined device's ids as its place's map names them, and back.

A device numbers its frames from its own first frame, and the map it held before its map
joined a place (:mod:`twinslam.slam.back_end.place_joining`) numbered its points from 1: both
collide with the ids of the place's first device. In the place's map the joined device's
keyframes, and the points its map held at the join, carry its tag
(:func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`); the points made since take
the place's next ids, and the device learns every id from its map updates. A place of
several devices may join another place in its turn: its first device's keyframes and points
— the untagged ones, the place's own ids — take that device's tag then, the other devices'
keep theirs, and each device of it has gone through two joins (:class:`PlaceJoin`, one
each). So what the device sends is renamed where it comes in:

* a frame id is always the device's own: tagged with its tag in its place now;
* a map point id is renamed by every join made after the map version the device read it
  from (the version each summary and upload names), oldest first: a point of a map version
  sent after the last join is the place's; a summary of unknown version is taken as the
  place's;
* track ids are the device's and stay so (each device has its own tracks table).

What goes out to the device (the frames a slot asks it to upload) is renamed back. A frame is
renamed once, where it comes in (:meth:`EdgeMapperCore.resolve_tracks`, which a plan calls
unless its caller did): a point of the old map fused into one of the place's is that point's
id afterwards, which renaming again would take for an old id. The place's first device has no
tag: its ids are the place's, and nothing is renamed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from edge_mapper.slot_planner import FrameObservations
from twinslam.slam.back_end.foreign_keyframes import source_id, under_tag
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload


@dataclass(frozen=True)
class PlaceJoin:
    """One join a device's map went through: the ids of the map it was in before, as the
    place it joined names them."""

    #: the tag the joining map's own ids (its first device's keyframes, its untagged points)
    #: took; ids tagged already (another device's of that map) keep theirs
    tag: int
    #: the newest map version the device was sent before the join: the ids of a frame
    #: tracked on it or an older one are the joining map's
    joined_at: int
    #: the joining map's points (under their new ids) that the join fused into the place's:
    #: the place's point each became
    fused: Mapping[int, int] = field(default_factory=dict)

    def keyframe(self, kf_id: int) -> int:
        """A keyframe (or frame) of the joining map, as the place names it."""
        return under_tag(kf_id, self.tag)

    def point(self, point_id: int) -> int:
        """A map point of the joining map, as the place names it."""
        renamed = self.keyframe(point_id)
        return self.fused.get(renamed, renamed)

    def observations(self, frame: FrameObservations) -> FrameObservations:
        """A frame whose ids are the joining map's (one that came in before the join), as
        the place names it."""
        return dataclasses.replace(frame, frame_id=self.keyframe(frame.frame_id),
                                   map_points=frozenset(map(self.point, frame.map_points)))

    def upload(self, data: KeyFramePayload) -> KeyFramePayload:
        """An upload whose ids are the joining map's, as the place names it."""
        return dataclasses.replace(data, frame_id=self.keyframe(data.frame_id),
                                   point_ids=_renamed_points(data.point_ids, self.point))


@dataclass(frozen=True)
class PlaceIds:
    """How one device's ids become its place's (see the module's text)."""

    #: the device's tag in its place (0: the place's first device, or a device of no place)
    tag: int = 0
    #: the joins its map went through, oldest first
    joins: tuple[PlaceJoin, ...] = ()

    def joined(self, tag: int, join: PlaceJoin) -> PlaceIds:
        """These ids after one more join, the device's tag ``tag`` in the new place."""
        return PlaceIds(tag, (*self.joins, join))

    @property
    def fused(self) -> dict[int, int]:
        """Every join's fused points: a point of a map the device was in → the point of the
        place's it became."""
        fused: dict[int, int] = {}
        for join in self.joins:
            fused = {old: join.fused.get(new, new) for old, new in fused.items()}
            fused.update(join.fused)
        return fused

    def point_at(self, point_id: int, version: int) -> int:
        """A map point the device read from its map version ``version`` (-1: unknown, taken
        as the place's), as the place names it now."""
        point_id = int(point_id)
        for join in self.joins:
            if 0 <= version <= join.joined_at:
                point_id = join.point(point_id)
        return point_id

    def frame(self, frame_id: int) -> int:
        """A frame of the device, as the place names it."""
        return self.tag | int(frame_id)

    def device_frame(self, frame_id: int) -> int:
        """A frame as the device names it (``frame_id``: the place's)."""
        return source_id(frame_id) if self.tag else int(frame_id)

    def _renames(self, version: int) -> bool:
        return any(0 <= version <= join.joined_at for join in self.joins)

    def observations(self, frame: FrameObservations) -> FrameObservations:
        """A slot's frame as the place names it."""
        if not self.tag:
            return frame
        points = frame.map_points
        if self._renames(frame.map_version):
            points = frozenset(self.point_at(p, frame.map_version) for p in points)
        if frame.frame_id == self.frame(frame.frame_id) and points is frame.map_points:
            return frame
        return dataclasses.replace(frame, frame_id=self.frame(frame.frame_id),
                                   map_points=points)

    def upload(self, data: KeyFramePayload, version: int) -> KeyFramePayload:
        """An uploaded keyframe as the place names it, tracked on the device's map version
        ``version`` (-1: unknown, taken as the place's)."""
        if not self.tag:
            return data
        ids = data.point_ids
        if self._renames(version):
            ids = _renamed_points(ids, lambda p: self.point_at(p, version))
        return dataclasses.replace(data, frame_id=self.frame(data.frame_id), point_ids=ids)


def _renamed_points(point_ids: np.ndarray, rename: Callable[[int], int]) -> np.ndarray:
    """An upload's point ids with its map points renamed (0: no point; a track id, its top
    bit set: the device's own, kept)."""
    ids = np.asarray(point_ids, dtype=np.uint64).copy()
    points = (ids != 0) & ((ids & TRACK_ID_BIT) == 0)
    ids[points] = [rename(p) for p in ids[points].tolist()]
    return ids
