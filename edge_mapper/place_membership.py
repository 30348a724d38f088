"""What a device's checkpoint keeps of the place its map was merged into, so that an edge
restarted from its checkpoints — or a standby edge taking its devices over — serves the place
it left instead of each map alone.

A merged map is in another device's frame (its ``frame_correction`` and the copies it adopted
are in its checkpoint already), but which device that is, and how far its copies followed
each lender's loops, lived only in the edge process's :class:`~edge_mapper.place_merging.
PlaceMerging`. Without them a restarted edge saw every map as a place of its own: no lending
until a look found the place again (a merge by a motion near the identity, measured anew), and
the loops a lender closed before the restart applied to the copies a second time.

The copies' tags need nothing here: a lender's tag is a function of its device name
(:func:`source_of`), the same in every edge process.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from twinslam.slam.back_end.foreign_keyframes import MAX_SOURCES

#: the checkpoint's arrays of a device's place
ROOT, LENDERS, FOLLOWED = "place_root", "place_lenders", "place_followed"


@functools.cache
def source_of(device: str) -> int:
    """The source index of ``device``'s keyframes in the maps that adopt them (their tag,
    :func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`): a hash of its name, so
    every edge process — the one that lent them, one restarted, a standby — tags a device's
    copies alike whatever order it met the devices in. Two names of one edge that hash alike
    are told apart by :class:`~edge_mapper.place_merging.PlaceMerging` (the later one lends
    nothing): with 2²² − 1 tags, 1 in ~3 000 edges of fifty devices has such a pair."""
    digest = hashlib.blake2b(device.encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "big") % MAX_SOURCES


@dataclass(frozen=True)
class PlaceMembership:
    """A device's place as its checkpoint records it."""

    #: the place's root: the device whose frame this map is in ("": its own, or unmerged)
    root: str = ""
    #: lender → how many of the lender's loops this map's copies of its keyframes followed
    followed: Mapping[str, int] = field(default_factory=dict)

    def arrays(self) -> dict[str, np.ndarray]:
        """The record as checkpoint arrays (strings as unicode arrays: no pickle needed)."""
        lenders = sorted(self.followed)
        return {ROOT: np.array(self.root), LENDERS: np.array(lenders, dtype=np.str_),
                FOLLOWED: np.array([self.followed[d] for d in lenders], dtype=np.int64)}

    @classmethod
    def read(cls, extra: Mapping[str, np.ndarray]) -> PlaceMembership:
        """The record in a checkpoint's ``extra`` arrays (none: a map of its own — a
        checkpoint written before the edge recorded places, or by an unmerged edge)."""
        if ROOT not in extra:
            return cls()
        lenders = [str(d) for d in np.atleast_1d(extra.get(LENDERS, ()))]
        counts = [int(n) for n in np.atleast_1d(extra.get(FOLLOWED, ()))]
        if len(lenders) != len(counts):
            raise ValueError(f"a checkpoint's place record names {len(lenders)} lenders and "
                             f"{len(counts)} loop counts")
        return cls(str(extra[ROOT]), dict(zip(lenders, counts, strict=True)))
