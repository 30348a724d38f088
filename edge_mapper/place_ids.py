"""A joined device's ids as its place's map names them, and back.

A device numbers its frames from its own first frame, and the map it held before its map
joined a place (:mod:`twinslam.slam.back_end.place_joining`) numbered its points from 1: both
collide with the ids of the place's first device. In the place's map the joined device's
keyframes, and the points its map held at the join, carry its tag
(:func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`); the points made since take
the place's next ids, and the device learns every id from its map updates. So what the device
sends is renamed where it comes in:

* a frame id is always the device's own: tagged;
* a map point id is the place's if the device read it from a map version sent after the join,
  and its old map's — tagged — if from one sent at or before it (the map version each summary
  and upload names); a summary of unknown version is taken as the place's;
* track ids are the device's and stay so (each device has its own tracks table).

What goes out to the device (the frames a slot asks it to upload) is renamed back. A frame is
renamed once, where it comes in (:meth:`EdgeMapperCore.resolve_tracks`, which a plan calls
unless its caller did): a point of the old map fused into one of the place's is that point's
id afterwards, which renaming again would take for an old id. The place's first device has no
tag: its ids are the place's, and nothing is renamed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from edge_mapper.slot_planner import FrameObservations
from twinslam.slam.back_end.foreign_keyframes import source_id
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload


@dataclass(frozen=True)
class PlaceIds:
    """How one device's ids become its place's (see the module's text)."""

    #: the device's tag in its place (0: the place's first device, or a device of no place)
    tag: int = 0
    #: the newest map version the device was sent before its map joined the place: the
    #: point ids of a frame tracked on it or an older one are its old map's
    joined_at: int = -1
    #: its old map's points (tagged) that the join fused into the place's: the place's point
    #: each became
    fused: Mapping[int, int] = field(default_factory=dict)

    def point(self, point_id: int) -> int:
        """A map point of the device's old map, as the place names it now."""
        tagged = self.tag | int(point_id)
        return self.fused.get(tagged, tagged)

    def frame(self, frame_id: int) -> int:
        """A frame of the device, as the place names it."""
        return self.tag | int(frame_id)

    def device_frame(self, frame_id: int) -> int:
        """A frame as the device names it (``frame_id``: the place's)."""
        return source_id(frame_id) if self.tag else int(frame_id)

    def _old_map(self, version: int) -> bool:
        return bool(self.tag) and 0 <= version <= self.joined_at

    def observations(self, frame: FrameObservations) -> FrameObservations:
        """A slot's frame as the place names it."""
        if not self.tag:
            return frame
        points = frame.map_points
        if self._old_map(frame.map_version):
            points = frozenset(map(self.point, points))
        if frame.frame_id == self.frame(frame.frame_id) and points is frame.map_points:
            return frame
        return dataclasses.replace(frame, frame_id=self.frame(frame.frame_id),
                                   map_points=points)

    def upload(self, data: KeyFramePayload, version: int) -> KeyFramePayload:
        """An uploaded keyframe as the place names it, tracked on the device's map version
        ``version`` (-1: unknown, taken as the place's)."""
        if not self.tag:
            return data
        ids = np.asarray(data.point_ids, dtype=np.uint64)
        if self._old_map(version):
            points = (ids != 0) & ((ids & TRACK_ID_BIT) == 0)
            ids = ids.copy()
            ids[points] = [self.point(p) for p in ids[points].tolist()]
        return dataclasses.replace(data, frame_id=self.frame(data.frame_id), point_ids=ids)
