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
  there at the join carries the tag;
* what is the joining device's own becomes its record in the place's back end
  (:class:`~twinslam.slam.back_end.device_record.DeviceRecord`): its slice holds its own
  keyframes as it held them, its tracks resolve to the moved points, its keyframes keep their
  entry order and capture times, and its frame moves by the alignment from its next map
  version, as :meth:`MapBackEnd.align` would have moved it.

What it does not do (the next steps of §10): the points two devices made of one corner stay
two points until a slice that takes in the other's keyframe fuses them, as a restore does;
the joining map's loop edges stay behind (its walk enters the place's graph as the other
device's keyframes, which the place's loops hold still); and a map that adopted copies of
another device's keyframes cannot join — lending and joining are two ways to share a place,
and a device is in one of them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twinslam.slam.back_end.device_record import DeviceRecord
from twinslam.slam.back_end.foreign_keyframes import foreign_mask, is_foreign
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.map_back_end import MapBackEnd


def join_into_place(place: MapBackEnd, joining: MapBackEnd, tag: int,
                    alignment: np.ndarray) -> DeviceRecord:
    """The map of ``joining``'s device, found in ``place`` with the rigid motion ``alignment``
    (its frame into the place's), joined into ``place`` under the device tag ``tag`` (see the
    module's text); the device's record there. ``joining`` is left as it was: its device is
    served by ``place`` from now on, and the caller stops using it (closing its loop
    closer)."""
    alignment = np.asarray(alignment, dtype=np.float64)
    if alignment.shape != (4, 4) or not np.isfinite(alignment).all():
        raise ValueError("an alignment is a finite 4×4 rigid motion")
    if len(joining.devices) != 1:
        raise ValueError("a back end that serves several devices cannot join another place")
    if any(is_foreign(k) for k in joining.store.ids()):
        raise ValueError("a map holding copies of another device's keyframes cannot join a "
                         "place: lending and joining are two ways to share it")
    own = joining.device
    record = place.add_device(tag, own.k, origin=alignment @ own.origin)
    points = _move_points(place.map, joining.map, tag, alignment)
    keyframe_ids = _move_keyframes(place.map, joining, tag, alignment, points)
    place.store.entered(keyframe_ids, record.slice)
    archived = [_moved_archived(kf, tag, alignment, own.k) for kf in joining.archive]
    place.archive_keyframes(archived, "writing the joined map's archived keyframes' files")
    _carry_record(record, own, tag, alignment, points)
    return record


def _move_points(place: KeyFrameMap, joining: KeyFrameMap, tag: int,
                 alignment: np.ndarray) -> dict[int, int]:
    """Every point of ``joining`` into ``place``, moved by ``alignment``, under its tagged id;
    its id there by its id in ``joining``."""
    ids, rows = joining.point_rows()
    tagged = [tag | p for p in ids.tolist()]
    positions = joining.columns.positions[rows] @ alignment[:3, :3].T + alignment[:3, 3]
    place.readd_points(tagged, positions, joining.columns.descriptors[rows])
    return dict(zip(ids.tolist(), tagged, strict=True))


def _move_keyframes(place: KeyFrameMap, joining: MapBackEnd, tag: int, alignment: np.ndarray,
                    points: dict[int, int]) -> list[int]:
    """Every keyframe of ``joining``'s map into ``place``, moved by ``alignment``, under its
    tagged id, observing the moved points where it saw them, read with the joining device's
    camera; the tagged ids."""
    moved = []
    camera = joining.device.k
    for kf_id, kf in joining.map.keyframes.items():
        place.add_keyframe(tag | kf_id, alignment @ kf.pose,
                           camera if kf.intrinsics is None else kf.intrinsics)
        seen, uvd = kf.observed()
        place.observe_many(tag | kf_id, [points[p] for p in seen.tolist()],
                           uvd[:, :2].tolist(), uvd[:, 2].tolist())
        moved.append(tag | kf_id)
    return moved


def _moved_archived(kf: ArchivedKeyFrame, tag: int, alignment: np.ndarray,
                    camera: np.ndarray) -> ArchivedKeyFrame:
    """An archived keyframe of the joining map as the place's archive keeps it: moved, its id
    and its points' ids tagged, its camera named."""
    own_points = ~foreign_mask(kf.point_ids)
    return dataclasses.replace(
        kf, id=tag | kf.id, pose=alignment @ kf.pose,
        point_ids=np.where(own_points, kf.point_ids | tag, kf.point_ids),
        positions=kf.positions @ alignment[:3, :3].T + alignment[:3, 3],
        intrinsics=camera.copy() if kf.intrinsics is None else kf.intrinsics)


def _carry_record(record: DeviceRecord, own: DeviceRecord, tag: int, alignment: np.ndarray,
                  points: dict[int, int]) -> None:
    """What the joining device's record held, under the place's ids: its tracks' points, its
    keyframes' entry order and capture times, its map versions' frames — moved by the
    alignment from its next version, as a merge's motion moves them."""
    record.local_mapping.track_points = {t: points[p] for t, p in
                                         own.local_mapping.track_points.items() if p in points}
    record.local_mapping.new_tracks = {t: points[p] for t, p in
                                       own.local_mapping.new_tracks.items() if p in points}
    record.entered.update({tag | k: entry for k, entry in own.entered.items()})
    record.keyframe_stamps.update({tag | k: t for k, t in own.keyframe_stamps.items()})
    record.version = own.version
    record.frame_correction = own.frame_correction.copy()
    record.frames_since = [(v, c.copy()) for v, c in own.frames_since]
    record.frame_moved(alignment)
