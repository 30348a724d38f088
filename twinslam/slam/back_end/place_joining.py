"""A device's map joined into the map of its place: one store a place instead of copies lent.

Once a merge has found a device's map in another device's place
(:mod:`~twinslam.slam.back_end.map_merging`: a keyframe recognised, confirmed, the rigid
motion between the two frames measured), the place can keep the joining map's keyframes
*once*, beside its own, instead of every map of the place holding welded copies of the
others' (docs/architecture.md §10, "Devices in one place", step 2(b)). This module moves them:

* every keyframe and point of the joining map, and every keyframe of its archive, enters the
  place's back end moved by the merge's ``alignment`` into the place's frame;
* under new ids: the joining device's tag in the bits above
  :data:`~twinslam.slam.back_end.foreign_keyframes.TAG_SHIFT` — its keyframe ids are its frame
  indices and its point ids its own map's count, both of which collide with the place's. A
  point made after the join takes the place's next id (one counter a place); only what was
  there at the join carries the tag. A joining place of several devices (two places that
  grew apart, each joined by others, then met) brings its other devices' keyframes and the
  points they made before they joined it under their tags already: those keep their ids, and
  only its first device's own — its keyframes, the place's untagged points — take the tag;
* what is each joining device's own becomes its record in the place's back end
  (:class:`~twinslam.slam.back_end.device_record.DeviceRecord`): its slice holds the
  keyframes it held, its tracks resolve to the moved points, its keyframes keep their entry
  order, capture times and the slots they were integrated at (which other walks' keyframes a
  walk's loop may close with), and its frame moves by the alignment from its next map
  version, as :meth:`MapBackEnd.align` would have moved it.

* the points the two devices made of one corner become one: each joining keyframe's points
  are looked for among the place's — projected where the keyframe saw them, alike, and near
  (:func:`~twinslam.slam.back_end.point_fusion.duplicates_in_view`, as a restored keyframe's
  are) — and a duplicate is fused into the place's point, the device's tracks following it.
  Without it the two walks of one room share no point: no keyframe of one is covisible with
  the other's, and a restore that would bring the other device's keyframe into a slice finds
  it cut off from the slice's keyframes.

What it does not do (the next steps of §10): the joining map's loop edges stay behind (its
walk enters the place's graph as the other device's keyframes, which the place's loops hold
still); and a map that adopted copies of another device's keyframes cannot join — lending and
joining are two ways to share a place, and a device is in one of them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.foreign_keyframes import (
    all_under_tag,
    is_foreign,
    tag_of,
    under_tag,
)
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.map_back_end import MapBackEnd, checked_alignment
from twinslam.slam.back_end.point_fusion import MapPoints, duplicates_in_view


def join_into_place(place: MapBackEnd, joining: MapBackEnd, tag: int,
                    alignment: np.ndarray) -> tuple[list[DeviceRecord], dict[int, int]]:
    """The map of ``joining``'s place, found in ``place`` with the rigid motion ``alignment``
    (its frame into the place's), joined into ``place``: its own ids — its first device's
    keyframes, its untagged points — under the device tag ``tag``, the ids of its other
    devices (a place of several devices) under their tags as they are (see the module's
    text); (each device's record there, in the order of ``joining.devices``; each of its
    points fused into the place's by the id it had in the place's map at the join: the
    place's point it became). ``joining`` is left as it was: its devices are served by
    ``place`` from now on, and the caller stops using it (closing its loop closer). A tag
    ``place`` has already, or ``joining`` holding copies lent by another map: ValueError,
    nothing changed."""
    alignment = checked_alignment(alignment)
    walks = {device.tag for device in joining.devices}
    if any(is_foreign(k) and tag_of(k) not in walks for k in joining.store.ids()):
        raise ValueError("a map holding copies of another device's keyframes cannot join a "
                         "place: lending and joining are two ways to share it")
    tags = [device.tag or tag for device in joining.devices]
    taken = {device.tag for device in place.devices}
    if tag in walks or len(set(tags)) != len(tags) or taken & set(tags):
        raise ValueError(f"the joining place's device tags {sorted(tags)} are not free in "
                         "the place")
    records = [place.add_device(new, device.k, origin=alignment @ device.origin)
               for new, device in zip(tags, joining.devices, strict=True)]
    points = _move_points(place.map, joining.map, tag, alignment)
    keyframe_ids = _move_keyframes(place.map, joining, tag, alignment, points)
    _hold_as_before(place, joining, records, tag, keyframe_ids)
    archived = [_moved_archived(kf, tag, alignment, joining.k)
                for kf in joining.archive]
    place.archive_keyframes(archived, "writing the joined map's archived keyframes' files")
    for record, device in zip(records, joining.devices, strict=True):
        _carry_record(record, device, tag, alignment, points)
    place.carry_integration_slots(
        {under_tag(k, tag): slot for k, slot in joining.integrated_at.items()},
        {(walk or tag): slot for walk, slot in joining.newest_slots().items()})
    return records, _fuse_duplicates(place, records, keyframe_ids)


def _move_points(place: KeyFrameMap, joining: KeyFrameMap, tag: int,
                 alignment: np.ndarray) -> dict[int, int]:
    """Every point of ``joining`` into ``place``, moved by ``alignment``, under its new id
    (:func:`under_tag`); its id there by its id in ``joining``."""
    ids, rows = joining.point_rows()
    renamed = all_under_tag(ids, tag).tolist()
    positions = joining.columns.positions[rows] @ alignment[:3, :3].T + alignment[:3, 3]
    place.readd_points(renamed, positions, joining.columns.descriptors[rows])
    return dict(zip(ids.tolist(), renamed, strict=True))


def _move_keyframes(place: KeyFrameMap, joining: MapBackEnd, tag: int, alignment: np.ndarray,
                    points: dict[int, int]) -> list[int]:
    """Every keyframe of ``joining``'s map into ``place``, moved by ``alignment``, under its
    new id, observing the moved points where it saw them, read with the camera that took
    it (the joining place's first device's, where the keyframe names none); the new ids."""
    moved = []
    camera = joining.k
    for kf_id, kf in joining.map.keyframes.items():
        new_id = under_tag(kf_id, tag)
        place.add_keyframe(new_id, alignment @ kf.pose,
                           camera if kf.intrinsics is None else kf.intrinsics)
        # in the order it came to observe them; a point seen with no measurement too (NaN)
        seen = [*kf.measurements, *sorted(p for p in kf.points if p not in kf.measurements)]
        uvd = [kf.measurements.get(p, (math.nan, math.nan, math.nan)) for p in seen]
        place.observe_many(new_id, [points[p] for p in seen],
                           [[u, v] for u, v, _ in uvd], [d for _, _, d in uvd])
        moved.append(new_id)
    return moved


def _hold_as_before(place: MapBackEnd, joining: MapBackEnd, records: list[DeviceRecord],
                    tag: int, moved: list[int]) -> None:
    """Each joining device's slice holds the moved keyframes it held before — in a place of
    several devices, two devices may hold one — and no device of ``place`` holds any."""
    moved_set = set(moved)
    for record, device in zip(records, joining.devices, strict=True):
        held = {under_tag(k, tag) for k in device.slice.keyframes}
        record.slice.set_apart(moved_set - held)
        record.slice.take_in(held)
    new_slices = [record.slice for record in records]
    for other in place.store.slices:
        if not any(other is mine for mine in new_slices):
            other.set_apart(moved_set)


def _moved_archived(kf: ArchivedKeyFrame, tag: int, alignment: np.ndarray,
                    camera: np.ndarray) -> ArchivedKeyFrame:
    """An archived keyframe of the joining map as the place's archive keeps it: moved, its
    id and its points' ids renamed (:func:`under_tag`), its camera named."""
    return dataclasses.replace(
        kf.moved(alignment), id=under_tag(kf.id, tag),
        point_ids=all_under_tag(kf.point_ids, tag),
        intrinsics=camera.copy() if kf.intrinsics is None else kf.intrinsics)


def _carry_record(record: DeviceRecord, own: DeviceRecord, tag: int, alignment: np.ndarray,
                  points: dict[int, int]) -> None:
    """What a joining device's record held, under the place's ids: its tracks' points, its
    keyframes' entry order and capture times, its map versions' frames — moved by the
    alignment from its next version, as a merge's motion moves them."""
    record.local_mapping.track_points = {t: points[p] for t, p in
                                         own.local_mapping.track_points.items() if p in points}
    record.local_mapping.new_tracks = {t: points[p] for t, p in
                                       own.local_mapping.new_tracks.items() if p in points}
    record.entered.update({under_tag(k, tag): entry for k, entry in own.entered.items()})
    record.keyframe_stamps.update({under_tag(k, tag): t
                                   for k, t in own.keyframe_stamps.items()})
    record.version = own.version
    record.frame_correction = own.frame_correction.copy()
    record.frames_since = [(v, c.copy()) for v, c in own.frames_since]
    record.frame_moved(alignment)


def _fuse_duplicates(place: MapBackEnd, records: list[DeviceRecord], keyframe_ids: list[int]
                     ) -> dict[int, int]:
    """The joined keyframes' points fused into the place's points that duplicate them (the
    place's own, not the joining map's: those are its map's, one a corner already), the
    joining devices' tracks following; each fused point's id → the place's point it
    became."""
    m = place.map
    joined = {p for k in keyframe_ids for p in m.keyframes[k].points}
    theirs = MapPoints.every(m, but=joined)  # a fusion keeps these: they stay as they are
    fused: dict[int, int] = {}
    for kf_id in keyframe_ids:
        kf = m.keyframes[kf_id]
        mine = [p for p in sorted(kf.points)
                if p in joined and p in m.points and p not in fused
                and p in kf.measurements and math.isfinite(kf.measurements[p][0])]
        pairs = duplicates_in_view(
            kf.pose, np.array([kf.measurements[p][:2] for p in mine], dtype=np.float64),
            m.descriptors_of(mine), m.positions_of(mine), theirs, place.camera_of(kf_id))
        now = {mine[row]: keep for row, keep in pairs}
        m.fuse_many([(keep, drop) for drop, keep in now.items()])
        fused.update(now)
    for record in records:
        for table in (record.local_mapping.track_points, record.local_mapping.new_tracks):
            for track, point in table.items():
                if point in fused:
                    table[track] = fused[point]
    return fused
