"""The edge's archive: every keyframe the managed map evicted, kept with what relocalisation
and a restore need — its pose, the map points it observed (position and descriptor) and where
it saw them — up to a capacity, the least recently useful leaving first.

V_max bounds the managed map: what the edge optimises and synchronises with the device every
slot (the paper's lever). It does not bound what the edge may remember. Evicting a keyframe
from the managed map moves it here instead of deleting it, as ORB-SLAM3's Atlas keeps every
map it built; a revisit of an evicted place can then be recognised and its keyframes brought
back, where before every revisit of an evicted place was a failure no policy could avoid.

Place recognition over the archive votes with binary descriptors in faiss' exact Hamming
index (``IndexBinaryFlat``) holding one descriptor a map point — a point seen by ten archived
keyframes is one place in the room, not ten (ORB-SLAM's keyframe database likewise lists a
keyframe under each word it holds, not a word under each observation). Each ORB descriptor of
the query frame finds its nearest point; when that point is near (``max_distance`` bits) and
clearly nearer than the next point (``ratio``, Lowe's test), it votes for every archived
keyframe that observed the point: a keyframe's votes are how many of the frame's features it
saw too. Indexed by observation instead, a well-observed point filled the nearest rows with
copies of itself (no runner-up: the ratio test was skipped) and voted for whichever keyframe
came first. A short walk's points are searched exactly; past EXACT_BELOW points the search
looks under each descriptor's nearest visual words only, a vocabulary the archive learns from
its own points (:mod:`~twinslam.slam.back_end.place_words`). The index is rebuilt only after
the archive changed.

With a folder, each archived keyframe is also one ``.npz`` file there, written when it is
archived (to a temporary name, then renamed) and deleted when it leaves — one taken back into
the map only once that map is checkpointed: the archive survives an edge restart, at any point
of a slot, without rewriting all of it every slot. Loops and merges move archived keyframes
without writing their files again: one pose file beside them says where each moved keyframe
stands now (:mod:`~twinslam.slam.back_end.archive_poses`). What a restart forgets is how
recently each keyframe was useful after it was archived (it restarts from the archival slots).

An archive whose files the edge's checkpoint writer lands (:attr:`KeyFrameArchive.write_later`,
with ``checkpoint_in_background``) does not write an evicted keyframe's file when it is
archived: writing and ``fsync``-ing it held the slot thread every device waits on ~1.2 ms an
eviction on an idle disk. The file is owed (:meth:`KeyFrameArchive.write_owed`) until just
before the next map checkpoint lands — the first one a restart could read without the
keyframe in its map. Until then a restart reads an older checkpoint, whose map still holds it.
A keyframe that leaves the archive for good meanwhile is owed no more (a late write would
bring its file back); one taken back into the map is still owed as it was archived: the
checkpoint about to land may be one gathered before it came back.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import Any

import numpy as np

from twinslam.npz_files import NPZ_READ_ERRORS, write_npz
from twinslam.slam.back_end.archive_poses import (
    POSES_NAME,
    MovedPose,
    PosesError,
    read_poses,
    write_poses,
)
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.place_words import DESCRIPTOR_BITS, PlaceWords

ARCHIVE_FORMAT = "twinslam-archived-keyframe-1"
#: an owed keyframe's file while it is written, before it takes its name
#: (:meth:`KeyFrameArchive.write_owed`); one an edge stopped beside is removed at its restart
STAGED_SUFFIX = ".owed"


class ArchiveError(ValueError):
    """An archived keyframe that cannot be read back, or one archived twice."""


@dataclass(frozen=True)
class ArchivedKeyFrame:
    """One evicted keyframe as it was when it left the managed map."""

    id: int
    pose: np.ndarray            #: 4×4 camera-to-map
    point_ids: np.ndarray       #: (n,) int64: the map points it observed
    positions: np.ndarray       #: (n, 3) their positions in the map frame
    descriptors: np.ndarray     #: (n, 32) uint8: their ORB descriptors
    measurements: np.ndarray    #: (n, 3): where it saw them, u, v and depth (NaN: none)
    archived_slot: int          #: the slot that evicted it
    #: 3×3 intrinsics of the camera that took it where it is another device's than the map's
    #: (:attr:`KeyFrame.intrinsics`); None: the map's own device's
    intrinsics: np.ndarray | None = None

    @classmethod
    def of(cls, m: KeyFrameMap, kf_id: int, slot: int) -> ArchivedKeyFrame:
        """Keyframe ``kf_id`` of ``m`` with its points, before it is evicted."""
        kf = m.keyframes[kf_id]
        ids, uvd = kf.observed()
        if len(ids) == len(kf.points):
            # the loop closer snapshots every keyframe of the map each slot: the keyframe's
            # observations as it keeps them, sorted by point
            order = np.argsort(ids, kind="stable")
            point_ids, measured = ids[order], uvd[order]
        else:                  # a point observed with no measurement: where it saw it is NaN
            point_ids = np.array(sorted(kf.points), dtype=np.int64)
            nan3 = (np.nan, np.nan, np.nan)
            measured = np.fromiter(
                chain.from_iterable(kf.measurements.get(p, nan3) for p in point_ids.tolist()),
                dtype=np.float64, count=3 * len(point_ids)).reshape(-1, 3)
        rows = m.columns.rows_of(point_ids)
        return cls(kf_id, kf.pose.copy(), point_ids, m.columns.positions[rows],
                   m.columns.descriptors[rows], measured, slot,
                   None if kf.intrinsics is None else kf.intrinsics.copy())

    def moved(self, motion: np.ndarray) -> ArchivedKeyFrame:
        """It and the points it saw moved by the rigid motion ``motion`` (4×4): a loop's
        correction, or a merge's alignment into another map's frame."""
        return dataclasses.replace(self, pose=motion @ self.pose,
                                   positions=self.positions @ motion[:3, :3].T + motion[:3, 3])

    def camera(self, own: np.ndarray) -> np.ndarray:
        """The intrinsics its measurements were taken with: its own, else ``own`` (the map's
        device's)."""
        return own if self.intrinsics is None else self.intrinsics

    @property
    def nbytes(self) -> int:
        """Memory its arrays take: 88 bytes a point (id, position, descriptor, measurement)
        and 128 for the pose."""
        return sum(a.nbytes for a in (self.pose, self.point_ids, self.positions,
                                      self.descriptors, self.measurements))

    def save(self, path: Path) -> None:
        """Write it to ``path`` atomically (:func:`~twinslam.npz_files.write_npz`)."""
        write_npz(path, {"format": np.array(ARCHIVE_FORMAT), "id": np.array(self.id),
                         "pose": self.pose, "point_ids": self.point_ids,
                         "positions": self.positions, "descriptors": self.descriptors,
                         "measurements": self.measurements,
                         "archived_slot": np.array(self.archived_slot),
                         **({} if self.intrinsics is None
                            else {"intrinsics": self.intrinsics})})

    @classmethod
    def load(cls, path: Path) -> ArchivedKeyFrame:
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["format"]) != ARCHIVE_FORMAT:
                    raise ArchiveError(f"{path}: not a {ARCHIVE_FORMAT} file")
                kf = cls(int(z["id"]), z["pose"].reshape(4, 4), z["point_ids"].astype(np.int64),
                         z["positions"].reshape(-1, 3), z["descriptors"].astype(np.uint8),
                         z["measurements"].reshape(-1, 3), int(z["archived_slot"]),
                         z["intrinsics"].reshape(3, 3).astype(np.float64)
                         if "intrinsics" in z.files else None)
        except NPZ_READ_ERRORS as exc:
            if isinstance(exc, ArchiveError):
                raise
            raise ArchiveError(f"{path}: not a readable archived keyframe ({exc})") from None
        n = len(kf.point_ids)
        if kf.descriptors.shape != (n, 32) or len(kf.positions) != n or \
                len(kf.measurements) != n:
            raise ArchiveError(f"{path}: its point arrays disagree in length")
        return kf


def restore_into(m: KeyFrameMap, kf: ArchivedKeyFrame) -> list[int]:
    """Put an archived keyframe back into the managed map ``m``: its pose, and its view of
    every point it observed — a point the map still holds keeps its current (optimised)
    position, one that left with the last of its observers comes back as archived. Returns
    the points that came back (which may duplicate points made since:
    :mod:`twinslam.slam.back_end.point_fusion`)."""
    m.add_keyframe(kf.id, kf.pose, kf.intrinsics)
    point_ids = np.asarray(kf.point_ids, dtype=np.int64)
    # each point the map lost, once, where it first comes (a keyframe archived before
    # welding kept its ids apart may name a point twice): asked of the map's columns at once
    lost = np.flatnonzero(~m.columns.holds(point_ids))
    _, first = np.unique(point_ids[lost], return_index=True)
    gone = lost[np.sort(first)]
    back: list[int] = point_ids[gone].tolist()
    m.readd_points(back, kf.positions[gone], kf.descriptors[gone])
    m.observe_many(kf.id, point_ids.tolist(), kf.measurements[:, :2].tolist(),
                   kf.measurements[:, 2].tolist())
    return back


def point_id_sets(in_map: Mapping[int, Collection[int]],
                  archive: Iterable[ArchivedKeyFrame]) -> dict[int, np.ndarray]:
    """Each keyframe's map points as int64 arrays without repeats — those of ``in_map``
    (keyframe id → its point ids: a managed map's) and of the ``archive``'s keyframes not
    among them — the sets the pose graphs count shared points over."""
    points = {k: np.fromiter(ids, dtype=np.int64, count=len(ids)) for k, ids in in_map.items()}
    for kf in archive:
        if kf.id not in points:
            points[kf.id] = np.unique(kf.point_ids.astype(np.int64))
    return points


class KeyFrameArchive:
    """Archived keyframes by id, at most ``capacity`` (0: none kept), with place recognition.

    "Useful" is the slot a keyframe was last archived, recognised or otherwise used
    (:meth:`touch`); past the capacity the least recently useful one leaves (the oldest id
    among equals)."""

    def __init__(self, capacity: int, folder: Path | None = None,
                 words: PlaceWords | None = None) -> None:
        if capacity < 0:
            raise ValueError(f"an archive holds 0 or more keyframes, not {capacity}")
        self.capacity = int(capacity)
        self.folder = Path(folder) if folder is not None else None
        self._entries: dict[int, ArchivedKeyFrame] = {}
        self._useful: dict[int, int] = {}
        self._index: Any = None
        #: the index's points and their keyframes
        self._places: _PointObservers | KeptPlaceIndex = _PointObservers.empty()
        #: the vocabulary place recognition files a large archive's points under, shared with
        #: every view of this archive (learned once, not for each loop job's view)
        self.words = words if words is not None else PlaceWords()
        #: keyframes taken back into the map whose files stay until its checkpoint
        self._taken: set[int] = set()
        #: one writer of a keyframe's file at a time: the loop closer's worker writes adopted
        #: keyframes' files while the edge archives and removes others
        self._files = threading.Lock()
        #: (pose, archival slot) each keyframe's file on disk holds (taken ones' too)
        self._on_file: dict[int, tuple[np.ndarray, int]] = {}
        #: the keyframes a correction moved from where their files hold them
        self._moved: dict[int, MovedPose] = {}
        #: one writer of the pose file at a time (its contents gathered and written in order)
        self._poses_file = threading.Lock()
        #: a loop closer's index this view searches, kept from view to view (:meth:`only`),
        #: and its synchronisation that holds this view's keyframes
        self._kept_index: KeptPlaceIndex | None = None
        self._synced_at = -1
        #: archived keyframes' files are written by :meth:`write_owed` (the checkpoint
        #: writer's thread, before each map checkpoint) instead of when they are archived
        self.write_later = False
        #: the keyframes whose files are owed (under ``_files``), as each file is to hold it
        self._owed: dict[int, ArchivedKeyFrame] = {}

    # -- contents ---------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._entries

    def __iter__(self) -> Iterator[ArchivedKeyFrame]:
        return iter(self._entries.values())

    def get(self, kf_id: int) -> ArchivedKeyFrame:
        return self._entries[kf_id]

    @property
    def nbytes(self) -> int:
        """Memory the archived keyframes' arrays take."""
        return sum(kf.nbytes for kf in self._entries.values())

    # -- edits ------------------------------------------------------------------------------

    def add(self, kf: ArchivedKeyFrame, write: bool = True) -> list[int]:
        """Archive ``kf`` (useful as of its archival slot); returns the ids that left to keep
        the capacity — ``kf`` itself when the capacity is 0. Its file is written now
        (``write``; else :meth:`save` it later, off the slot's path) — or owed until
        :meth:`write_owed` where the archive :attr:`write_later`."""
        if kf.id in self._entries:
            raise ArchiveError(f"keyframe {kf.id} is archived already")
        if self.capacity == 0:
            return [kf.id]
        self._entries[kf.id] = kf
        self._useful[kf.id] = kf.archived_slot
        # taken back and archived again before the map's checkpoint: the file is this
        # keyframe's again, not one for the checkpoint to release
        self._taken.discard(kf.id)
        if self.folder is not None and write and self.write_later:
            with self._files:
                self._owed[kf.id] = kf
        elif self.folder is not None and write:
            self.folder.mkdir(parents=True, exist_ok=True)
            with self._files:
                kf.save(self._path(kf.id))
                self._written(kf)
        self._index = None
        return self._trim()

    def write_owed(self) -> int:
        """Write the files owed (:attr:`write_later`), each as the keyframe stands now — or,
        taken back into the map since, as it was archived. The checkpoint writer calls it
        before it writes the map checkpoint; a write that fails raises, and what was not
        written stays owed. How many files were written.

        Each file is written and flushed to the disk beside its final name, outside the lock
        the slot thread takes to archive or drop a keyframe — on a slow disk one ``fsync``
        would hold every device's slot — and renamed into place under it, only if the
        keyframe is still owed as it was written: one dropped meanwhile gets no file, one
        archived again or moved by a loop meanwhile is written again as it is now."""
        if self.folder is None:
            return 0
        with self._files:
            owed = list(self._owed)
        if owed:
            self.folder.mkdir(parents=True, exist_ok=True)
        written = 0
        for kf_id in owed:
            path = self._path(kf_id)
            staged = path.with_name(path.name + STAGED_SUFFIX)
            while True:
                with self._files:
                    kf = self._owed.get(kf_id)
                if kf is None:                 # left the archive for good, or written
                    break
                kf.save(staged)
                with self._files:
                    if self._owed.get(kf_id) is kf:
                        staged.replace(path)
                        self._written(kf)
                        written += 1
                        break
                staged.unlink(missing_ok=True)  # changed while it was written: again
        return written

    @property
    def owed(self) -> int:
        """How many archived keyframes' files are owed (:attr:`write_later`)."""
        return len(self._owed)

    def _written(self, kf: ArchivedKeyFrame) -> None:
        """``kf``'s file now holds it as it is (under ``_files``): no move to record, nothing
        owed."""
        self._on_file[kf.id] = (kf.pose, kf.archived_slot)
        self._moved.pop(kf.id, None)
        self._owed.pop(kf.id, None)

    def _trim(self) -> list[int]:
        """Drop the least recently useful keyframes past the capacity; their ids."""
        dropped = []
        while len(self._entries) > self.capacity:
            stale = min(self._entries, key=lambda k: (self._useful[k], k))
            self._remove(stale)
            dropped.append(stale)
        return dropped

    def touch(self, kf_ids: list[int], slot: int) -> None:
        """Mark archived keyframes useful as of ``slot`` (recognised, planned for a restore)."""
        for k in kf_ids:
            if k in self._useful:
                self._useful[k] = max(self._useful[k], slot)

    def correct(self, corrections: Mapping[int, np.ndarray], min_move_m: float = 1e-3,
                write: bool = True) -> list[int]:
        """Move archived keyframes by a loop's corrections (keyframe id → 4×4 map-frame
        correction, corrected · before⁻¹): each one's pose and the points it keeps, as the
        managed map's keyframes move (:mod:`twinslam.slam.back_end.loop_correction`). Where
        each moved keyframe stands is written to the archive's pose file (``write``; else
        :meth:`save_poses` later, off the slot's path), so a restarted edge reads the
        corrected archive; its own file is not written again
        (:mod:`~twinslam.slam.back_end.archive_poses`). A correction that moves none of the
        keyframe's points (nor its camera) by ``min_move_m`` is left out: a loop bends the
        walk where it drifted, and sub-millimetre moves are not worth recording. The place
        index stays: descriptors do not move. Returns the ids moved."""
        moved = []
        for kf_id in sorted(corrections.keys() & self._entries.keys()):
            c = np.asarray(corrections[kf_id], dtype=np.float64)
            kf = self._entries[kf_id]
            reach = np.vstack([kf.pose[:3, 3], kf.positions])
            shift = reach @ (c[:3, :3] - np.eye(3)).T + c[:3, 3]      # where each moves
            if np.linalg.norm(shift, axis=1).max(initial=0.0) < min_move_m:
                continue
            now = kf.moved(c)
            self._entries[kf_id] = now
            with self._files:
                if kf_id in self._owed:        # no file yet: it is to be written as it is now
                    self._owed[kf_id] = now
                elif (held := self._on_file.get(kf_id)) is not None:
                    self._moved[kf_id] = MovedPose(held[0], held[1], now.pose)
            moved.append(kf_id)
        if write and moved:
            self.save_poses()
        return moved

    def save_poses(self) -> None:
        """Write the pose file: where every keyframe a correction moved stands now, beside
        the pose its file holds (:mod:`~twinslam.slam.back_end.archive_poses`). The loop
        closer's worker calls it after a loop or a merge moved the archive; one file, however
        many keyframes moved."""
        if self.folder is None:
            return
        with self._poses_file:
            with self._files:
                moved = dict(self._moved)
            self.folder.mkdir(parents=True, exist_ok=True)
            write_poses(self.folder / POSES_NAME, moved)

    def save(self, kf_ids: Iterable[int]) -> None:
        """Write the files of the archived keyframes ``kf_ids`` as they are now (one that left
        the archive meanwhile is skipped): the loop closer's worker calls it after a
        correction or an adoption, beside the slots."""
        if self.folder is None:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        for kf_id in kf_ids:
            with self._files:
                kf = self._entries.get(kf_id)
                if kf is not None:
                    kf.save(self._path(kf_id))
                    self._written(kf)

    def snapshot(self, extra: Iterable[ArchivedKeyFrame] = (),
                 index: KeptPlaceIndex | None = None) -> KeyFrameArchive:
        """A read-only view for another thread: the same archived keyframes (immutable, shared)
        plus ``extra`` ones, no folder; later edits of this archive do not reach it. Without
        ``extra`` it shares the place index when one is built (faiss searches it read-only);
        with ``index`` (kept by its one searcher from view to view) it searches that one,
        brought up to the view's keyframes (:mod:`~twinslam.slam.back_end.place_index`)."""
        added = list(extra)
        view = KeyFrameArchive(len(self._entries) + len(added), words=self.words)
        view._entries = dict(self._entries)
        view._useful = dict(self._useful)
        for kf in added:
            view._entries[kf.id] = kf
            view._useful[kf.id] = kf.archived_slot
        view._kept_index = index
        if not added and index is None and self._index is not None and \
                self._kept_index is None:
            view._index, view._places = self._index, self._places
        return view

    def only(self, keep: Callable[[int], bool], index: KeptPlaceIndex | None = None
             ) -> KeyFrameArchive:
        """A read-only view of the archived keyframes whose ids ``keep`` accepts, with a place
        index of their points alone (built when first searched): a search that can choose
        among some keyframes only — a loop among the walk's own — need not compare every
        descriptor with the points of the rest. Keeping all, it is :meth:`snapshot`. With
        ``index`` (a loop closer's, kept from its last job) the view's index is that one,
        brought up to the view's keyframes instead of built anew
        (:mod:`~twinslam.slam.back_end.place_index`)."""
        kept = {k: kf for k, kf in self._entries.items() if keep(k)}
        if len(kept) == len(self._entries):
            return self.snapshot(index=index)
        view = KeyFrameArchive(len(kept), words=self.words)
        view._entries = kept
        view._useful = {k: self._useful[k] for k in kept}
        view._kept_index = index
        return view

    def drop(self, kf_id: int) -> ArchivedKeyFrame:
        """Remove an archived keyframe for good, its file with it (one kept elsewhere: another
        device's keyframe, copied again when this map needs it); returns it."""
        kf = self._entries[kf_id]
        self._remove(kf_id)
        return kf

    def take(self, kf_id: int) -> ArchivedKeyFrame:
        """Remove and return an archived keyframe (it goes back into the managed map). Its
        file stays until :meth:`release_taken`, which the edge calls once the map holding it
        is checkpointed: an edge stopped in between restarts from the older map, which lacks
        the keyframe, and finds it in the archive still."""
        kf = self._entries[kf_id]
        self._remove(kf_id, keep_file=True)
        if self.folder is not None:
            self._taken.add(kf_id)
        return kf

    def release_taken(self) -> None:
        """Delete the files of the keyframes taken back since the last call (the map holding
        them was just checkpointed)."""
        self.release(self.hand_over_taken())

    def hand_over_taken(self) -> frozenset[int]:
        """The keyframes taken back since the last call, whose files a checkpoint of the map
        gathered now releases once it is on disk (:meth:`release`)."""
        taken, self._taken = frozenset(self._taken), set()
        return taken

    def release(self, kf_ids: Collection[int], in_map: Collection[int] | None = None) -> None:
        """Delete the files of keyframes ``kf_ids`` taken back into a map now checkpointed,
        those the checkpoint's map holds (``in_map``; None: all of them) and this archive
        does not hold again. A checkpoint written off the slot thread lands slots later:
        a keyframe archived again meanwhile has its file back, and one the checkpoint
        holds archived (a newer checkpoint written in place of the one that took it)
        needs it — a restart from that checkpoint would find it nowhere else."""
        held = None if in_map is None else set(np.asarray(in_map, dtype=np.int64).tolist())
        with self._files:
            for kf_id in kf_ids:
                if kf_id not in self._entries and (held is None or kf_id in held):
                    self._path(kf_id).unlink(missing_ok=True)
                    self._forget_file(kf_id)

    def _forget_file(self, kf_id: int) -> None:
        """Keyframe ``kf_id``'s file is gone, or is to be written no more (under ``_files``):
        nothing of it to record."""
        self._on_file.pop(kf_id, None)
        self._moved.pop(kf_id, None)
        self._owed.pop(kf_id, None)

    def _remove(self, kf_id: int, keep_file: bool = False) -> None:
        del self._entries[kf_id]
        del self._useful[kf_id]
        self._index = None
        if self.folder is not None and not keep_file:
            with self._files:
                self._path(kf_id).unlink(missing_ok=True)
                self._forget_file(kf_id)

    def _path(self, kf_id: int) -> Path:
        assert self.folder is not None
        return self.folder / f"keyframe-{kf_id:09d}.npz"

    # -- persistence ------------------------------------------------------------------------

    @classmethod
    def restore(cls, capacity: int, folder: Path, in_map: set[int] | frozenset[int] = frozenset()
                ) -> tuple[KeyFrameArchive, list[str]]:
        """The archive saved in ``folder`` (empty when there is none) and a note per file that
        could not be read (skipped, left in place). A keyframe that is also in the managed
        map (``in_map``: the edge stopped after archiving it, before its map checkpoint) is
        the map's: its file is removed. Each keyframe a loop or a merge moved since its file
        was written stands where the pose file has it; a pose file that cannot be read is
        named too, and the keyframes stand where their files have them."""
        archive = cls(capacity, folder)
        problems: list[str] = []
        if not folder.is_dir():
            return archive, problems
        kfs = []
        for staged in folder.glob(f"keyframe-*.npz{STAGED_SUFFIX}*"):
            staged.unlink(missing_ok=True)    # a write of an owed file the stop cut short
        for path in sorted(folder.glob("keyframe-*.npz")):
            try:
                kfs.append(ArchivedKeyFrame.load(path))
            except ArchiveError as exc:
                problems.append(str(exc))
        try:
            moved = read_poses(folder / POSES_NAME)
        except PosesError as exc:
            problems.append(str(exc))
            moved = {}
        for kf in sorted(kfs, key=lambda k: (k.archived_slot, k.id)):
            if kf.id in in_map:
                archive._path(kf.id).unlink(missing_ok=True)
                continue
            archive._on_file[kf.id] = (kf.pose, kf.archived_slot)
            if (entry := moved.get(kf.id)) is not None and \
                    entry.matches(kf.pose, kf.archived_slot):
                c = entry.motion()
                kf = dataclasses.replace(kf, pose=entry.pose.copy(),
                                         positions=kf.positions @ c[:3, :3].T + c[:3, 3])
                archive._moved[kf.id] = entry
            archive._entries[kf.id] = kf
            archive._useful[kf.id] = kf.archived_slot
        archive._trim()
        return archive, problems

    # -- place recognition ------------------------------------------------------------------

    def shared_with(self, kf_id: int) -> dict[int, int]:
        """How many map points each other archived keyframe shares with ``kf_id`` (those that
        share none left out): one pass over the observations, not a set per keyframe."""
        self._built_index()
        return self._places.shared_with(kf_id)

    def recognise(self, descriptors: np.ndarray, top: int = 3, max_distance: int = 50,
                  ratio: float = 0.8, eligible: Callable[[int], bool] | None = None
                  ) -> list[tuple[int, int]]:
        """The archived keyframes that best explain a frame's ORB ``descriptors`` ((n, 32)
        uint8): (keyframe id, votes), most votes first, at most ``top``, none without a vote,
        only keyframes ``eligible`` accepts (None: all) — a loop ranks the old walk alone, so
        the recent keyframes, which share the most with a new one, take no candidate's place.
        A descriptor votes when its nearest map point is within ``max_distance`` bits and
        nearer than ``ratio`` × the next point's distance, for every keyframe that observed
        that point."""
        query = np.ascontiguousarray(descriptors, dtype=np.uint8)
        if query.ndim != 2 or query.shape[1] != DESCRIPTOR_BITS // 8:
            raise ValueError(f"ORB descriptors are (n, 32) uint8, got {query.shape}")
        if not self._entries or not len(query):
            return []
        index = self._built_index()
        places = self._places
        if not places.points:
            return []
        k = min(2, places.points)
        distances, rows = index.search(query, k)
        best = distances[:, 0]
        votes_for = (rows[:, 0] >= 0) & (best <= max_distance)
        if k > 1:                              # an archive of one point has no runner-up
            votes_for &= ~((rows[:, 1] >= 0) & (best >= ratio * distances[:, 1]))
        kfs, votes = places.votes(rows[votes_for, 0])
        ranked = sorted(((kf, v) for kf, v in zip(kfs.tolist(), votes.tolist(), strict=True)
                         if eligible is None or eligible(kf)),
                        key=lambda kv: (-kv[1], kv[0]))
        return ranked[:top]

    def _built_index(self) -> Any:
        kept = self._kept_index
        if kept is not None and (self._index is None or kept.syncs != self._synced_at):
            # (again, where another view synchronised the kept index since: its keyframes)
            if kept.sync(self._entries, self.words):
                self._index = self._places = kept
                self._synced_at = kept.syncs
            else:
                self._kept_index = None            # its keyframes disagree: built below
                self._index = None
        if self._index is None:
            kfs = list(self._entries.values())
            self._places = _PointObservers.of(kfs)
            self._index = self.words.index(self._places.descriptors, [k.id for k in kfs],
                                           [k.descriptors for k in kfs], self._places.source)
        return self._index


@dataclass(frozen=True)
class _PointObservers:
    """The archive's map points, one row each (the index's rows), and the keyframes that
    observed each: its observations sorted by point, ``start[r]:start[r + 1]`` those of row r."""

    descriptors: np.ndarray     #: (points, 32) uint8: each point's newest archived descriptor
    #: (points,) int64: where each row's descriptor is among the keyframes' descriptors laid
    #: end to end (the keyframe's words are filed in the same order)
    source: np.ndarray
    start: np.ndarray           #: (points + 1,) int64: where each row's observations begin
    keyframe_of: np.ndarray     #: (observations,) int64, sorted by point
    point_of: np.ndarray        #: (observations,) int64, sorted

    @classmethod
    def empty(cls) -> _PointObservers:
        none = np.zeros(0, dtype=np.int64)
        return cls(np.zeros((0, 32), dtype=np.uint8), none, np.zeros(1, dtype=np.int64), none,
                   none)

    @classmethod
    def of(cls, keyframes: list[ArchivedKeyFrame]) -> _PointObservers:
        """The points of ``keyframes`` (archived first to last: a later copy of a point's
        descriptor is the map's newer one)."""
        if not keyframes:
            return cls.empty()
        point = np.concatenate([k.point_ids for k in keyframes])
        keyframe = np.concatenate([np.full(len(k.point_ids), k.id, dtype=np.int64)
                                   for k in keyframes])
        descriptors = np.concatenate([k.descriptors for k in keyframes])
        # sorted by point, a point's observations in archive order: its last is the newest
        order = np.lexsort((np.arange(len(point)), point))
        point, keyframe, descriptors = point[order], keyframe[order], descriptors[order]
        first = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
        last = np.r_[first[1:], len(point)] - 1
        return cls(np.ascontiguousarray(descriptors[last]), order[last],
                   np.r_[first, len(point)].astype(np.int64), keyframe, point)

    @property
    def points(self) -> int:
        return len(self.start) - 1

    def votes(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(keyframe ids ascending, votes): every keyframe that observed the point at each of
        ``rows`` gets a vote (a row given twice, two)."""
        kfs, votes = np.unique(self.observers(rows), return_counts=True)
        return kfs, votes

    def shared_with(self, kf_id: int) -> dict[int, int]:
        """How many observations of keyframe ``kf_id``'s points each other keyframe has
        (those with none left out)."""
        others = self.keyframe_of != kf_id
        rows = np.isin(self.point_of, self.point_of[~others]) & others
        ids, counts = np.unique(self.keyframe_of[rows], return_counts=True)
        return dict(zip(ids.tolist(), counts.tolist(), strict=True))

    def observers(self, rows: np.ndarray) -> np.ndarray:
        """The keyframe of every observation of the points at ``rows`` (a keyframe once per
        row it observed; rows may repeat)."""
        begin, count = self.start[rows], np.diff(self.start)[rows]
        # each row's run of observations laid end to end: begin + 0, 1, …, count − 1
        offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        kfs: np.ndarray = self.keyframe_of[np.repeat(begin, count) + offsets]
        return kfs
