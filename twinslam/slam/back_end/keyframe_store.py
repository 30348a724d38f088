"""Every keyframe one device's edge map keeps, as one store: the slice the device holds and the
rest, archived.

The paper's map management bounds what the edge optimises and synchronises with a device — at
most V_max keyframes, the *slice* (here the managed :class:`KeyFrameMap`) — not what the edge
remembers. A keyframe the policy evicts leaves the slice, not the store: it waits in the
archive (:class:`KeyFrameArchive`, bounded by its own capacity) until a restore brings it back
where the camera heads, a loop or a merge finds its place, or the archive forgets it.

Questions about the whole store (is this keyframe kept? where is every keyframe now? which
points does each see?) were answered by hand, map and archive side by side, in each of their
askers; a store answers them once. It is the first step of one map a place
(docs/architecture.md §10, "Devices in one place"): a place's store will hold every device's
keyframes, and each device's slice will name the ones it holds.

The slice's keyframes live in the map with their points, as ORB-SLAM's active map does; the
archived ones keep the points they saw as copies (:class:`ArchivedKeyFrame`). Moving a keyframe
between the two (:meth:`KeyFrameStore.leave_slice`, :meth:`KeyFrameStore.enter_slice`) is what
an eviction and a restore do to the store; what else they do to the map (the points a restore
brings back fused with their copies) is the back end's.
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
from twinslam.slam.back_end.place_index import KeptPlaceIndex


class KeyFrameStore:
    """One device's keyframes at the edge: the slice (``managed``, the map the device holds)
    and the ``archive``. A keyframe is in one of the two, never both."""

    def __init__(self, managed: KeyFrameMap, archive: KeyFrameArchive) -> None:
        self.managed = managed
        self.archive = archive

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

    def leave_slice(self, keyframes: Iterable[int], slot: int) -> tuple[list[int], int]:
        """``keyframes`` out of the slice into the archive at ``slot``; (the archived keyframes
        the archive forgot to keep its capacity, the points that lost their last observer)."""
        forgotten, orphans = [], 0
        for kf in keyframes:
            forgotten += self.archive.add(ArchivedKeyFrame.of(self.managed, kf, slot))
            orphans += len(self.managed.evict(kf))
        return forgotten, orphans

    def enter_slice(self, keyframes: Iterable[ArchivedKeyFrame]) -> dict[int, list[int]]:
        """Archived keyframes, taken from the archive (:meth:`KeyFrameArchive.take`), back into
        the slice; each one's points that came back with it (which may duplicate points the
        map made since)."""
        return {archived.id: restore_into(self.managed, archived) for archived in keyframes}
