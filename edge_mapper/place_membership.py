"""What a device's checkpoint keeps of the place its map was merged into, so that an edge
restarted from its checkpoints — or a standby edge taking its devices over — serves the place
it left instead of each map alone.

A merged map is in another device's frame (its ``frame_correction`` and the copies it adopted
are in its checkpoint already), but which device that is, and how far its copies followed
each lender's loops, lived only in the edge process's :class:`~edge_mapper.place_merging.
PlaceMerging`. Without them a restarted edge saw every map as a place of its own: no lending
until a look found the place again (a merge by a motion near the identity, measured anew), and
the loops a lender closed before the restart applied to the copies a second time.

The copies' tags need little here: a lender's tag is a function of its device name
(:func:`source_of`), the same in every edge process, and of which of its maps it is — the
edge starts a device a new map when it reclaims it or the device starts again, and the new
map counts keyframe and point ids from where any device starts. Its copies in other maps must
not carry the old map's tag: a borrower would take the new keyframes for copies it holds
already and weld the new points to the old map's points of the same ids. So the record keeps
the map's run (0 for a device's first map).

It keeps too the slot each lender's keyframe, held back out of the device's view and not lent
yet, was first offered at (:attr:`~twinslam.slam.back_end.map_merging.Lender.offered`): a copy
counts as adopted then, and a loop across devices closes only with copies adopted a while
before. Without it a restarted edge counted every keyframe still held back as first offered
at the restart: where the device came to it, its lender had been there longer than the copy
said, and a loop across with it waited slots it need not have.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twinslam.npz_files import NPZ_READ_ERRORS
from twinslam.slam.back_end.foreign_keyframes import MAX_SOURCES
from twinslam.slam.back_end.keyframe_map import MapError

#: the checkpoint's arrays of a device's place
ROOT, LENDERS, FOLLOWED, RUN = "place_root", "place_lenders", "place_followed", "place_run"
#: the checkpoint's arrays of the keyframes offered and not lent yet: one entry a keyframe
OFFERED_BY, OFFERED, OFFERED_AT = ("place_offered_lenders", "place_offered_keyframes",
                                   "place_offered_slots")


@functools.cache
def source_of(device: str, run: int = 0) -> int:
    """The source index of the keyframes of ``device``'s map number ``run`` (0: its first)
    in the maps that adopt them (their tag,
    :func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`): a hash of its name and
    run, so every edge process — the one that lent them, one restarted, a standby — tags a
    device's copies alike whatever order it met the devices in. A first map's tag hashes the
    name alone (as before runs were counted: copies checkpointed then keep their tag). Two
    names of one edge that hash alike are told apart by
    :class:`~edge_mapper.place_merging.PlaceMerging` (the later one lends nothing): with
    2²² − 1 tags, 1 in ~3 000 edges of fifty devices has such a pair."""
    if run < 0:
        raise ValueError(f"a device's map run counts from 0, not {run}")
    # a ROS name holds no NUL: no name and run hash as another name would
    key = device if run == 0 else f"{device}\0{run}"
    digest = hashlib.blake2b(key.encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "big") % MAX_SOURCES


@dataclass(frozen=True)
class PlaceMembership:
    """A device's place as its checkpoint records it."""

    #: the place's root: the device whose frame this map is in ("": its own, or unmerged)
    root: str = ""
    #: lender → how many of the lender's loops this map's copies of its keyframes followed
    followed: Mapping[str, int] = field(default_factory=dict)
    #: which of the device's maps this is (0: its first; one more each time the edge started
    #: it a new one): its copies' tag (:func:`source_of`)
    run: int = 0
    #: lender → its keyframes offered to this map and not lent yet (held back out of the
    #: device's view) → the slot each was first offered at
    offered: Mapping[str, Mapping[int, int]] = field(default_factory=dict)

    def arrays(self) -> dict[str, np.ndarray]:
        """The record as checkpoint arrays (strings as unicode arrays: no pickle needed)."""
        lenders = sorted(self.followed)
        entries = [(lender, kf, slot) for lender in sorted(self.offered)
                   for kf, slot in sorted(self.offered[lender].items())]
        return {ROOT: np.array(self.root), LENDERS: np.array(lenders, dtype=np.str_),
                FOLLOWED: np.array([self.followed[d] for d in lenders], dtype=np.int64),
                RUN: np.array(self.run, dtype=np.int64),
                OFFERED_BY: np.array([e[0] for e in entries], dtype=np.str_),
                OFFERED: np.array([e[1] for e in entries], dtype=np.int64),
                OFFERED_AT: np.array([e[2] for e in entries], dtype=np.int64)}

    @classmethod
    def read(cls, extra: Mapping[str, np.ndarray]) -> PlaceMembership:
        """The record in a checkpoint's ``extra`` arrays (none: a map of its own — a
        checkpoint written before the edge recorded places, or by an unmerged edge; no run:
        one written before runs were counted, a first map); MapError where it contradicts
        itself, as for a map that cannot be read."""
        if ROOT not in extra:
            return cls()
        run = int(extra.get(RUN, 0))
        if run < 0:
            raise MapError(f"a checkpoint's place record names map run {run}")
        lenders = [str(d) for d in np.atleast_1d(extra.get(LENDERS, ()))]
        counts = [int(n) for n in np.atleast_1d(extra.get(FOLLOWED, ()))]
        if len(lenders) != len(counts):
            raise MapError(f"a checkpoint's place record names {len(lenders)} lenders and "
                             f"{len(counts)} loop counts")
        by = [str(d) for d in np.atleast_1d(extra.get(OFFERED_BY, ()))]
        kfs = [int(k) for k in np.atleast_1d(extra.get(OFFERED, ()))]
        slots = [int(t) for t in np.atleast_1d(extra.get(OFFERED_AT, ()))]
        if not len(by) == len(kfs) == len(slots):
            raise MapError(f"a checkpoint's place record lists its offers with {len(by)} "
                           f"lenders, {len(kfs)} keyframes and {len(slots)} slots")
        offered: dict[str, dict[int, int]] = {}
        for lender, kf, slot in zip(by, kfs, slots, strict=True):
            offered.setdefault(lender, {})[kf] = slot
        return cls(str(extra[ROOT]), dict(zip(lenders, counts, strict=True)), run, offered)


def run_after(reclaimed: Path) -> int:
    """The run of a device's next map where its last one was set aside at ``reclaimed``
    (``FILE.reclaimed``): one past that map's (0: no such file). An edge that restarts
    before the new map's first checkpoint learns its run here; a file it cannot read counts
    as a first map set aside."""
    if not reclaimed.is_file():
        return 0
    try:
        with np.load(reclaimed, allow_pickle=False) as saved:
            extra = {k: saved[k] for k in (ROOT, RUN) if k in saved.files}
        return PlaceMembership.read(extra).run + 1
    except NPZ_READ_ERRORS:
        return 1
