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


def tag_of(item_id: int) -> int:
    """The source tag an id carries (0: a map's own)."""
    return int(item_id) >> TAG_SHIFT << TAG_SHIFT


def source_id(item_id: int) -> int:
    """The id a keyframe or point has in the map it came from (an own id as it is)."""
    return int(item_id) & ((1 << TAG_SHIFT) - 1)
