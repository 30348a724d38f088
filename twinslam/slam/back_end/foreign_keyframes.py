"""Keyframes and points another device's map lent this one, told apart by their ids.

A device's keyframe ids are its own frame indices and its points count from 1, so two devices'
maps reuse each other's ids. A keyframe one map adopts from another (once the two are merged
into one frame, :mod:`twinslam.slam.back_end.map_merging`) carries its source's tag in the
bits above :data:`TAG_SHIFT` — as do its points that the adopting map does not hold already —
and the adopting map treats it as another device's: its pose is the source map's, which this
map's loops do not move (:func:`is_foreign`), and it is no capture-order neighbour of the
map's own keyframes.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from twinslam.slam.back_end.pose_graph import Anchors
from twinslam.slam.sorted_ids import find_sorted

#: ids below 2**40 are a device's own: frame indices and point counts never reach it (a
#: device at 30 Hz for a thousand years), and the tag leaves the top bit free for the
#: device's track ids (``TRACK_ID_BIT``)
TAG_SHIFT = 40
#: sources a map may adopt from: tags 1 .. MAX_SOURCES
MAX_SOURCES = (1 << 22) - 1


def foreign_tag(source: int) -> int:
    """The tag of source map ``source`` (0, 1, …: the device's place among the edge's)."""
    if not 0 <= source < MAX_SOURCES:
        raise ValueError(f"source {source} is outside 0 .. {MAX_SOURCES - 1}")
    return (source + 1) << TAG_SHIFT


def is_foreign(item_id: int) -> bool:
    """Whether a keyframe or point id came from another device's map."""
    return int(item_id) >> TAG_SHIFT != 0


def foreign_mask(ids: np.ndarray) -> np.ndarray:
    """:func:`is_foreign` of every id of an int64 array at once."""
    mask: np.ndarray = (ids >> TAG_SHIFT) != 0
    return mask


def under_tag(item_id: int, tag: int) -> int:
    """A keyframe or point id of a map whose own ids take ``tag`` (a lent keyframe's points,
    a joining place's ids): its own (untagged) under the tag, another device's, tagged
    already, as it is — tagged again it would read as yet another device's."""
    return int(item_id) if is_foreign(item_id) else tag | int(item_id)


def all_under_tag(ids: np.ndarray, tag: int) -> np.ndarray:
    """:func:`under_tag` of every id of an int64 array at once."""
    renamed: np.ndarray = np.where(foreign_mask(ids), ids, ids | tag)
    return renamed


def tag_of(item_id: int) -> int:
    """The source tag an id carries (0: a map's own)."""
    return int(item_id) >> TAG_SHIFT << TAG_SHIFT


def source_id(item_id: int) -> int:
    """The id a keyframe or point has in the map it came from (an own id as it is)."""
    return int(item_id) & ((1 << TAG_SHIFT) - 1)


def keyframe_label(kf_id: int) -> str:
    """A keyframe as a log names it: "keyframe 30", or — another device's, a copy — "another
    device's keyframe 30 (copy 1099511628076)", its id in its own map first."""
    if not is_foreign(kf_id):
        return f"keyframe {kf_id}"
    return f"another device's keyframe {source_id(kf_id)} (copy {kf_id})"


def ties_to_copies(points: Mapping[int, np.ndarray], walk: int = 0
                   ) -> dict[tuple[int, int], int]:
    """How many of the points other keyframes brought each keyframe of walk ``walk`` (its
    tag; 0: the map's own) observes, by the keyframe that brought them: (walk's keyframe,
    other) → count (``points``: each keyframe's point ids, int64 without repeats). The
    others are another device's keyframes this map adopted (copies) or, in a place of
    several devices, the other walks' keyframes.

    A point a copy brought carries its source's tag (one a copy was welded to has this map's
    id: the map had placed it before the copy came); in a place of several devices a point
    of another tag than the walk's is one the walk did not make before it joined. Several
    others may observe it; the oldest of them brought it, and its pose placed it — a later
    copy observing it too stood, by the lender's own drift, wherever its walk had taken it,
    and a keyframe of the walk posed on that point was posed on where the oldest put it."""
    def brought_by_others(ids: np.ndarray) -> np.ndarray:
        others: np.ndarray = ids[(ids >> TAG_SHIFT << TAG_SHIFT) != walk]
        return others

    copies = [(k, brought_by_others(ids)) for k, ids in points.items() if tag_of(k) != walk]
    if not copies:
        return {}
    point = np.concatenate([ids for _, ids in copies])
    if not point.size:
        return {}
    holder = np.concatenate([np.full(len(ids), k, dtype=np.int64) for k, ids in copies])
    order = np.lexsort((holder, point))                   # by point, then oldest copy first
    point, holder = point[order], holder[order]
    first = np.r_[True, point[1:] != point[:-1]]
    brought, by = point[first], holder[first]
    ties: dict[tuple[int, int], int] = {}
    for k, ids in points.items():
        if tag_of(k) != walk:
            continue
        at, found = find_sorted(brought, brought_by_others(ids))
        copy, count = np.unique(by[at[found]], return_counts=True)
        ties.update({(int(k), int(c)): int(n) for c, n in zip(copy, count, strict=True)})
    return ties


def copy_anchors(points: Mapping[int, np.ndarray], before: Mapping[int, np.ndarray],
                 now: Mapping[int, np.ndarray], walk: int = 0) -> Anchors:
    """The keyframes of other walks than ``walk`` — copies of another device's keyframes,
    or in a place of several devices its other walks (``before``: where the walk's keyframes
    were posed on them; ``now``: where they are) — as the anchors of the walk's graph
    (:class:`~twinslam.slam.back_end.pose_graph.Anchors`), tied by the points each brought
    (:func:`ties_to_copies`; ``points``: every keyframe's point ids)."""
    return Anchors(before, now, ties_to_copies(points, walk),
                   {k: len(ids) for k, ids in points.items() if tag_of(k) == walk})
