"""Every keyframe the edge keeps of a place, as one store: the map the place's devices hold
slices of, and the rest, archived.

The paper's map management bounds what the edge optimises and synchronises with a device — at
most V_max keyframes, the device's *slice* (:class:`KeyFrameSlice`) — not what the edge
remembers. A keyframe the policy evicts leaves the slice, not the store: while another device
of the place holds it, it stays in the map; else it waits in the archive
(:class:`KeyFrameArchive`, bounded by its own capacity) until a restore brings it back where
the camera heads, a loop or a merge finds its place, or the archive forgets it.

Questions about the whole store (is this keyframe kept? where is every keyframe now? which
points does each see?) were answered by hand, map and archive side by side, in each of their
askers; a store answers them once. It is the data model of one map a place
(docs/architecture.md §10, "Devices in one place"): a place's store holds every device's
keyframes once, and each device's slice names the ones it holds. Until a merge joins stores
(step 2(b) there) every store is one device's, with one slice that holds its whole map.

The map's keyframes live in it with their points, as ORB-SLAM's active map does; the
archived ones keep the points they saw as copies (:class:`ArchivedKeyFrame`). Moving a keyframe
between the two (:meth:`KeyFrameStore.leave_slice`, :meth:`KeyFrameStore.enter_slice`) is what
an eviction and a restore do to the store, and a keyframe another device holds moves into a
slice as it is (:meth:`KeyFrameStore.take_from_place`); what else they do to the map (the
points a restore brings back fused with their copies) is the back end's.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from twinslam.slam.back_end.keyframe_archive import (
    ArchivedKeyFrame,
    KeyFrameArchive,
    point_id_sets,
    restore_into,
)
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.keyframe_slice import KeyFrameSlice
from twinslam.slam.back_end.place_index import KeptPlaceIndex


class KeyFrameStore:
    """The keyframes at the edge of one place: those some device holds, in the map
    (``managed``), and the ``archive``. A keyframe is in one of the two, never both. Each
    device of the place holds a slice of the map (:attr:`slices`): the first the store was
    made for (:attr:`slice`), one more for each device that joins it (:meth:`add_slice`)."""

    def __init__(self, managed: KeyFrameMap, archive: KeyFrameArchive) -> None:
        self.managed = managed
        self.archive = archive
        #: what the device's map update, uncertainty, policy and evictions read of the map:
        #: every keyframe of it while the store is one device's (its map is its place's)
        self.slice = KeyFrameSlice(managed)
        #: every device's slice of the map, :attr:`slice` first
        self.slices: list[KeyFrameSlice] = [self.slice]

    def add_slice(self, holds: Iterable[int]) -> KeyFrameSlice:
        """A slice for another device of the place, holding the map's keyframes ``holds``
        (those the map keeps); the map's other keyframes are set apart from it."""
        held = set(holds)
        joining = KeyFrameSlice(self.managed)
        joining.set_apart(k for k in self.managed.keyframes if k not in held)
        self.slices.append(joining)
        return joining

    def entered(self, keyframes: Iterable[int], by: KeyFrameSlice | None = None) -> None:
        """``keyframes`` entered the map for the device of slice ``by`` (default
        :attr:`slice`; an upload integrated, or a restore): no other device holds them."""
        by = by or self.slice
        ids = list(keyframes)
        for other in self.slices:
            if other is not by:
                other.set_apart(ids)
        by.take_in(ids)

    def held_elsewhere(self, kf_id: int, by: KeyFrameSlice) -> bool:
        """Whether a device other than ``by``'s holds keyframe ``kf_id``."""
        return any(other.holds(kf_id) for other in self.slices if other is not by)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self.managed.keyframes or kf_id in self.archive

    def __len__(self) -> int:
        return len(self.managed.keyframes) + len(self.archive)

    def ids(self) -> list[int]:
        """Every keyframe kept: the archive's, then the slice's (the order the edge's
        snapshots and checkpoints have always listed them in)."""
        return [*(kf.id for kf in self.archive), *self.managed.keyframes]

    def in_slice(self, kf_id: int) -> bool:
        """Whether the device holds keyframe ``kf_id`` (else it is archived, or not kept)."""
        return kf_id in self.managed.keyframes

    def poses(self) -> dict[int, np.ndarray]:
        """Every keyframe kept by id, where the edge holds it now — the slice's as copies:
        another thread may read them while the map moves on."""
        poses = {kf.id: kf.pose for kf in self.archive}
        poses.update({k: kf.pose.copy() for k, kf in self.managed.keyframes.items()})
        return poses

    def point_sets(self) -> dict[int, np.ndarray]:
        """Each kept keyframe's map points (int64, no repeats): what the pose graphs count
        shared points over."""
        return point_id_sets({k: kf.points for k, kf in self.managed.keyframes.items()},
                             self.archive)

    def descriptors(self) -> Iterator[tuple[int, np.ndarray]]:
        """Each kept keyframe's id and its points' ORB descriptors, the archive's first: what
        a restored map files in the process's keyframe database
        (:mod:`~twinslam.slam.back_end.keyframe_database`)."""
        for kf in self.archive:
            yield kf.id, kf.descriptors
        for kf_id in list(self.managed.keyframes):
            yield kf_id, self.managed.descriptors_of(self.managed.point_array(kf_id))

    def snapshot(self, slot: int, index: KeptPlaceIndex | None = None) -> KeyFrameArchive:
        """Every keyframe kept, the slice's as they are at ``slot``, as one archive to
        recognise places in, searched under ``index`` where its one searcher keeps one from
        snapshot to snapshot. It shares nothing mutable with the store, and may be searched
        beside the slots."""
        return self.archive.snapshot([ArchivedKeyFrame.of(self.managed, k, slot)
                                      for k in self.managed.keyframes], index)

    def leave_slice(self, keyframes: Iterable[int], slot: int,
                    by: KeyFrameSlice | None = None) -> tuple[list[int], int]:
        """``keyframes`` out of slice ``by`` (default :attr:`slice`): those another device
        still holds stay in the map, set apart from ``by``; the rest leave the map for the
        archive at ``slot``. (The archived keyframes the archive forgot to keep its capacity,
        the points that lost their last observer.)"""
        by = by or self.slice
        forgotten, orphans = [], 0
        for kf in keyframes:
            if self.held_elsewhere(kf, by):
                by.set_apart([kf])
                continue
            forgotten += self.archive.add(ArchivedKeyFrame.of(self.managed, kf, slot))
            orphans += len(self.managed.evict(kf))
            for each in self.slices:
                each.left_place([kf])
        return forgotten, orphans

    def take_from_place(self, keyframes: Iterable[int], by: KeyFrameSlice) -> list[int]:
        """Keyframes of the map another device holds, into slice ``by`` as they are (their
        points are the place's already: nothing to fuse); the ones it took."""
        taken = [k for k in keyframes if k in self.managed.keyframes and not by.holds(k)]
        by.take_in(taken)
        return taken

    def enter_slice(self, keyframes: Iterable[ArchivedKeyFrame],
                    by: KeyFrameSlice | None = None) -> dict[int, list[int]]:
        """Archived keyframes, taken from the archive (:meth:`KeyFrameArchive.take`), back into
        the map and slice ``by`` (default :attr:`slice`) alone; each one's points that came
        back with it (which may duplicate points the map made since)."""
        back = {archived.id: restore_into(self.managed, archived) for archived in keyframes}
        self.entered(back, by)
        return back
