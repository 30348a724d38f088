"""A loop closer's place index, kept from one loop job to the next and edited, not built anew.

Each loop job searches a view of the archive (:meth:`KeyFrameArchive.only`: the walk's own
keyframes old enough to close a loop with, the map's among them), and a view built its index
from nothing: every observation of every keyframe sorted by point, then every point filed in
faiss. On an archive of 500 keyframes of the 7-Scenes walk (434 000 points) that was most of
a loop job (``bench.loop_closer``) — for every device, every slot, once an edge has run for
some minutes — while from one job to the next the view gains the few keyframes that grew old
enough and loses the few restored or forgotten.

This index keeps the points of the keyframes it was last synchronised with, one row a point,
how many observations each row has, and each keyframe's rows. :meth:`KeptPlaceIndex.sync`
removes the keyframes that left (the points nobody observes any more taken out of faiss) and
adds those that came (their new points filed), then lays the observations end to end for the
votes. It answers what the view's own index answers, vote for vote: the same points, each under
the one descriptor every keyframe holds for it (a point's descriptor is fixed when its map
makes it), searched exactly below the vocabulary's threshold and under the same words above
it. Where two keyframes hold a point under different descriptors it declines, from then on,
and each view builds its own index as before.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from twinslam.slam.back_end.place_words import DESCRIPTOR_BITS, PlaceVocabulary, PlaceWords

#: the row arrays grow by at least this many rows at a time
GROWTH = 4096


class IndexedKeyFrame(Protocol):
    """What the index reads of an archived keyframe."""

    @property
    def id(self) -> int: ...

    @property
    def point_ids(self) -> np.ndarray:
        """(n,) int64: the points it observed."""

    @property
    def descriptors(self) -> np.ndarray:
        """(n, 32) uint8: their descriptors."""


def votes_of(rows: np.ndarray, obs_rows: np.ndarray, obs_kf: np.ndarray, capacity: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """(keyframe ids ascending, votes): each of ``rows`` (a point's row, once per descriptor
    that voted for it) votes for every observation of that point (``obs_rows[i]`` observed by
    keyframe ``obs_kf[i]``)."""
    hits = np.bincount(rows, minlength=capacity)[obs_rows]
    voted = hits > 0
    kfs, at = np.unique(obs_kf[voted], return_inverse=True)
    return kfs, np.bincount(at, weights=hits[voted], minlength=len(kfs)).astype(np.int64)


class KeptPlaceIndex:
    """The points of a set of archived keyframes, searchable and counted, edited from one set
    to the next (see the module's text). One thread at a time: a loop closer's jobs run one
    after another."""

    def __init__(self) -> None:
        self.syncs = 0                  #: synchronisations that answered
        self.declined = 0               #: synchronisations that declined
        self._reset()

    def _reset(self) -> None:
        self._members: dict[int, IndexedKeyFrame] = {}
        self._kf_rows: dict[int, np.ndarray] = {}      #: keyframe id → its observations' rows
        self._row_of: dict[int, int] = {}               #: point id → row
        self._point = np.zeros(0, dtype=np.int64)       #: row → point id
        self._count = np.zeros(0, dtype=np.int64)       #: row → observations
        self._desc = np.zeros((0, DESCRIPTOR_BITS // 8), dtype=np.uint8)
        self._used = 0                                  #: rows handed out at the end
        self._free: list[int] = []
        self._faiss: Any = None
        self._filed_with: PlaceVocabulary | None = None  #: None: an exact index (or none)
        self._added: list[int] = []                     #: rows not filed yet
        self._removed: list[int] = []                   #: filed rows to take out
        self._obs_rows = np.zeros(0, dtype=np.int64)
        self._obs_kf = np.zeros(0, dtype=np.int64)

    @property
    def points(self) -> int:
        """Points held: the rows a search may answer."""
        return len(self._row_of)

    @property
    def nbytes(self) -> int:
        """Memory its arrays and faiss' copy of the descriptors take (its dict of rows, ~100
        bytes a point more, left out)."""
        arrays = (self._point, self._count, self._desc, self._obs_rows, self._obs_kf)
        filed = 0 if self._faiss is None else self._faiss.ntotal * (DESCRIPTOR_BITS // 8 + 8)
        return sum(a.nbytes for a in arrays) + int(filed)

    # -- the set of keyframes ----------------------------------------------------------------

    def sync(self, keyframes: Mapping[int, IndexedKeyFrame], words: PlaceWords) -> bool:
        """Hold exactly the points of ``keyframes`` (id → archived keyframe), searched as a
        view of an archive sharing ``words`` searches them; False where two of them hold a
        point under different descriptors (the index is emptied: the caller builds its own)
        — and from then on at once: keyframes that disagreed once may again, and each try
        would fill the index anew before it finds out."""
        if self.declined:
            return False
        try:
            if not self._edit(keyframes, words):
                self._reset()
                self.declined += 1
                return False
        except BaseException:
            self._reset()          # half edited (a failure in faiss, an interrupt): start afresh
            raise
        order = list(self._kf_rows)
        self._obs_rows = np.concatenate([self._kf_rows[k] for k in order]) if order \
            else np.zeros(0, dtype=np.int64)
        self._obs_kf = np.repeat(np.array(order, dtype=np.int64),
                                 [len(self._kf_rows[k]) for k in order])
        self.syncs += 1
        return True

    def _edit(self, keyframes: Mapping[int, IndexedKeyFrame], words: PlaceWords) -> bool:
        """The keyframes that left removed, those that came added and faiss told; False
        where one disagrees on a point's descriptor."""
        for kf_id in [k for k, kf in self._members.items()
                      if not _same_points(kf, keyframes.get(k))]:
            self._remove(kf_id)
        for kf_id, kf in keyframes.items():
            if kf_id not in self._members and not self._add(kf):
                return False
            self._members[kf_id] = kf
        self._file(words)
        return True

    def _add(self, kf: IndexedKeyFrame) -> bool:
        """Keyframe ``kf``'s observations counted, its new points given rows; False where it
        holds a point under another descriptor than the index does."""
        ids = np.asarray(kf.point_ids, dtype=np.int64).tolist()
        rows = np.empty(len(ids), dtype=np.int64)
        fresh = np.zeros(len(ids), dtype=bool)
        for i, pid in enumerate(ids):
            row = self._row_of.get(pid)
            if row is None:
                row = self._free.pop() if self._free else self._grow()
                self._row_of[pid] = row
                self._point[row] = pid
                fresh[i] = True
            rows[i] = row
        self._desc[rows[fresh]] = kf.descriptors[fresh]
        known = ~fresh
        if np.any(self._desc[rows[known]] != kf.descriptors[known]):
            return False                   # the caller empties the index
        # a keyframe may name a point twice: each observation counts, as in a view's index
        np.add.at(self._count, rows, 1)
        self._kf_rows[kf.id] = rows
        self._added.extend(np.unique(rows[fresh]).tolist())
        return True

    def _remove(self, kf_id: int) -> None:
        """Keyframe ``kf_id``'s observations uncounted; the points none observes any more
        out of the index."""
        rows = self._kf_rows.pop(kf_id)
        del self._members[kf_id]
        np.add.at(self._count, rows, -1)
        gone = np.unique(rows[self._count[rows] == 0])
        for pid in self._point[gone].tolist():
            del self._row_of[pid]
        self._point[gone] = -1
        self._free.extend(gone.tolist())
        self._removed.extend(gone.tolist())

    def _grow(self) -> int:
        """A new row at the end, the arrays grown where they are full."""
        row = self._used
        self._used += 1
        if row >= len(self._count):
            extra = max(GROWTH, len(self._count))
            self._point = np.concatenate([self._point, np.full(extra, -1, dtype=np.int64)])
            self._count = np.concatenate([self._count, np.zeros(extra, dtype=np.int64)])
            self._desc = np.concatenate([self._desc, np.zeros((extra, self._desc.shape[1]),
                                                              dtype=np.uint8)])
        return row

    # -- faiss ---------------------------------------------------------------------------------

    def _file(self, words: PlaceWords) -> None:
        """The rows added since the last sync filed in faiss and those removed taken out —
        or, where the search changes (exact ↔ under words, or new words), every row filed
        anew."""
        vocabulary = words.vocabulary_for(self.points, self._descriptors_by_point) \
            if self.points >= words.exact_below else None
        added = np.array(sorted(set(self._added)), dtype=np.int64)
        removed = np.array(sorted(set(self._removed)), dtype=np.int64)
        self._added, self._removed = [], []
        if self._faiss is None or vocabulary is not self._filed_with:
            live = np.array(sorted(self._row_of.values()), dtype=np.int64)
            self._faiss = _new_index(vocabulary)
            self._filed_with = vocabulary
            _file_rows(self._faiss, vocabulary, live, self._desc[live])
            return
        if len(removed):
            import faiss

            self._faiss.remove_ids(faiss.IDSelectorBatch(len(removed),
                                                         faiss.swig_ptr(removed)))
        if len(added):
            _file_rows(self._faiss, vocabulary, added, self._desc[added])

    def _descriptors_by_point(self) -> np.ndarray:
        """Every point's descriptor, by ascending point id (the order a view's index lays
        them in: the sample a vocabulary learns from is drawn from it)."""
        live = np.array(list(self._row_of.values()), dtype=np.int64)
        return np.ascontiguousarray(self._desc[live[np.argsort(self._point[live])]])

    # -- the answers ---------------------------------------------------------------------------

    def search(self, query: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(distances, rows) of each query descriptor's ``k`` nearest points (row -1: none)."""
        distances, rows = self._faiss.search(query, k)
        return distances, rows

    def votes(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(keyframe ids ascending, votes) the points at ``rows`` give (see :func:`votes_of`)."""
        return votes_of(rows, self._obs_rows, self._obs_kf, len(self._count))

    def shared_with(self, kf_id: int) -> dict[int, int]:
        """How many observations of keyframe ``kf_id``'s points each other keyframe has
        (those with none left out)."""
        mask = np.zeros(len(self._count), dtype=bool)
        mask[self._kf_rows[kf_id]] = True
        rows = mask[self._obs_rows] & (self._obs_kf != kf_id)
        ids, counts = np.unique(self._obs_kf[rows], return_counts=True)
        return dict(zip(ids.tolist(), counts.tolist(), strict=True))


def _same_points(held: IndexedKeyFrame, now: IndexedKeyFrame | None) -> bool:
    """Whether keyframe ``now`` holds the points ``held`` did under the same descriptors (a
    loop's correction moves a keyframe, not its points' ids; the map's keyframes are
    snapshot anew for each job, mostly unchanged)."""
    if now is None:
        return False
    if now is held:
        return True
    return bool(np.array_equal(held.point_ids, now.point_ids)
                and np.array_equal(held.descriptors, now.descriptors))


def _new_index(vocabulary: PlaceVocabulary | None) -> Any:
    """An empty faiss index whose ids are rows: exact, or the vocabulary's inverted file."""
    import faiss

    if vocabulary is None:
        return faiss.IndexBinaryIDMap(faiss.IndexBinaryFlat(DESCRIPTOR_BITS))
    return vocabulary.inverted_file(np.zeros((0, DESCRIPTOR_BITS // 8), dtype=np.uint8),
                                    np.zeros(0, dtype=np.int64))


def _file_rows(index: Any, vocabulary: PlaceVocabulary | None, rows: np.ndarray,
               descriptors: np.ndarray) -> None:
    """``descriptors`` filed in ``index`` under ids ``rows``."""
    if not len(rows):
        return
    codes = np.ascontiguousarray(descriptors, dtype=np.uint8)
    if vocabulary is None:
        index.add_with_ids(codes, np.ascontiguousarray(rows, dtype=np.int64))
    else:
        vocabulary.file(index, codes, vocabulary.assign(codes), rows)
