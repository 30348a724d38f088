"""Visual words for place recognition in a large archive: an inverted file over the archive's
map points, so that a query searches the points filed under its descriptors' nearest words
instead of every point.

Exact search compares each of a frame's ~1000 descriptors with every point of the archive: a
few milliseconds over a short walk's points, 0.3-0.5 s over an archive of 500 keyframes
(``bench.loop_closer``: 430 000 points) — and the loop closer runs it for every keyframe
a device uploads. ORB-SLAM's keyframe database answers from a bag of words (DBoW2), a
vocabulary learned offline from other images; here the archive learns its own: k-means over a
sample of its points' descriptors (faiss' binary k-means), the words it finds are the coarse
quantizer of faiss' binary inverted file (``IndexBinaryIVF``), and each query descriptor is
compared with the points of its PROBES nearest words. On an archive of 500 keyframes of the
7-Scenes walk (434 000 points: 1024 words, 16 probed) place recognition with its PnP took 72 ms
a frame against 306-322 searching every point, and found the same place and pose for all 20
frames (``bench.loop_closer``, 2026-11-30); learning the words took ~2 s, once.

Below EXACT_BELOW points the archive is searched exactly, as before: a short walk's answers do
not depend on a vocabulary. The vocabulary is learned once the archive first needs it (on the
thread that searches: the loop closer's or the merge looks' worker) and learned again when the
archive has grown EIGHTFOLD since; each archived keyframe's words are computed once and kept
with the vocabulary (an archive view built for every loop job files its points without
searching the vocabulary again).

The devices of one edge process search under one vocabulary (:meth:`PlaceWords.share`, the
edge's ``shared_vocabulary``), as ORB-SLAM's maps all search under one DBoW2 vocabulary: the
first archive that needs words learns them for every device, in whatever place. Each device's
archive learned its own before, ~0.7 s of k-means on the loop closer's worker once a device
(and all of them in the same slots where a fleet starts together). Words learned in one place
serve another: on an archive of 100 keyframes of the 7-Scenes walk, 60 frames found the same
place and pose under words learned from the synthetic corridor or from 30 SUN3D frames as
searching every point, with as many PnP inliers, and the corridor's archive under the
kitchen's words the same (``bench.loop_closer --words-from``, 2026-12-04). A process may
also turn it off: the devices of a merged place still share their root's words then.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: an ORB descriptor: 256 bits
DESCRIPTOR_BITS = 256
#: fewer points than this are searched exactly (a short walk, the tests' rooms)
EXACT_BELOW = 20_000
#: words a query descriptor's points are looked for under
PROBES = 16
#: the vocabulary's size: about four words per square root of the points, a power of two
#: within these bounds (faiss' rule of thumb for an inverted file's lists)
FEWEST_WORDS, MOST_WORDS = 256, 1024
#: descriptors k-means learns each word from (faiss warns under 39)
SAMPLES_A_WORD = 40
#: the vocabulary is learned again once the archive holds this many times the points it was
#: learned from
EIGHTFOLD = 8


def words_for(points: int) -> int:
    """The vocabulary's size for an archive of ``points`` points."""
    wanted = 4.0 * np.sqrt(max(points, 1))
    size = 1 << round(float(np.log2(wanted)))
    return int(min(max(size, FEWEST_WORDS), MOST_WORDS))


@dataclass(frozen=True)
class PlaceVocabulary:
    """Words learned from an archive's descriptors: faiss' binary k-means centroids."""

    quantizer: Any               #: faiss.IndexBinaryFlat of the words (faiss is typed loosely)
    words: int
    learned_from: int            #: the archive's points when it was learned
    serial: int                  #: which vocabulary of its archive (a keyframe's words name it)

    @classmethod
    def learn(cls, descriptors: np.ndarray, serial: int = 0, seed: int = 0,
              words: int | None = None) -> PlaceVocabulary:
        """k-means over a sample of ``descriptors`` ((n, 32) uint8), the same sample and
        words for the same descriptors; ``words`` words (None: :func:`words_for` the
        descriptors)."""
        import faiss

        words = words_for(len(descriptors)) if words is None else words
        rng = np.random.default_rng(seed)
        take = min(len(descriptors), SAMPLES_A_WORD * words)
        sample = np.ascontiguousarray(
            descriptors[np.sort(rng.choice(len(descriptors), take, replace=False))])
        quantizer = faiss.IndexBinaryFlat(DESCRIPTOR_BITS)
        learner = faiss.IndexBinaryIVF(quantizer, DESCRIPTOR_BITS, words)
        learner.train(sample)            # fills the quantizer with the words
        return cls(quantizer, words, len(descriptors), serial)

    def assign(self, descriptors: np.ndarray) -> np.ndarray:
        """Each descriptor's nearest word ((n,) int64)."""
        if not len(descriptors):
            return np.zeros(0, dtype=np.int64)
        _, nearest = self.quantizer.search(np.ascontiguousarray(descriptors, dtype=np.uint8), 1)
        return np.ascontiguousarray(nearest[:, 0], dtype=np.int64)

    def inverted_file(self, descriptors: np.ndarray, words: np.ndarray) -> object:
        """An inverted file of ``descriptors`` (row i filed under ``words[i]``), searched
        under each query descriptor's PROBES nearest words."""
        import faiss

        index = faiss.IndexBinaryIVF(self.quantizer, DESCRIPTOR_BITS, self.words)
        index.is_trained = True
        index.nprobe = min(PROBES, self.words)
        self.file(index, descriptors, words, np.arange(len(descriptors), dtype=np.int64))
        return index

    def file(self, index: Any, descriptors: np.ndarray, words: np.ndarray, ids: np.ndarray
             ) -> None:
        """``descriptors`` added to this vocabulary's inverted file ``index``, row i under
        ``words[i]`` with id ``ids[i]``."""
        import faiss

        codes = np.ascontiguousarray(descriptors, dtype=np.uint8)
        labels = np.ascontiguousarray(ids, dtype=np.int64)
        filed = np.ascontiguousarray(words, dtype=np.int64)
        if len(codes):
            # faiss reads the three arrays through raw pointers: they stay bound until it
            # returns
            index.add_core(len(codes), faiss.swig_ptr(codes),
                           faiss.swig_ptr(labels), faiss.swig_ptr(filed))


class PlaceWords:
    """The vocabulary of one archive and its keyframes' words, shared by the archive and every
    view of it (each loop job searches a view): learned by the first search that needs it,
    kept across the views. Searches on several threads (the loop closer, the merge looks) may
    build indexes at once: one learns, the others go on meanwhile with the vocabulary there
    is (none yet: they search exactly)."""

    def __init__(self, exact_below: int = EXACT_BELOW) -> None:
        self.exact_below = exact_below
        self.vocabulary: PlaceVocabulary | None = None
        self.learned = 0                     #: vocabularies learned (the first and again)
        #: the words whose vocabulary this archive searches under instead of its own
        #: (:meth:`share`; None: its own)
        self._shared: PlaceWords | None = None
        self._learning = threading.Lock()
        self._cache = threading.Lock()
        #: keyframe id → (its descriptors, its points' words, the vocabulary they are words
        #: of): a keyframe moved by a loop keeps its descriptors, and so its words; the map's
        #: keyframes a loop job snapshots anew each slot mostly keep theirs too
        self._words: dict[int, tuple[np.ndarray, np.ndarray, PlaceVocabulary]] = {}

    def share(self, other: PlaceWords) -> None:
        """Search under ``other``'s vocabulary from now on, not one of this archive's own —
        learned by whichever archive sharing it first needs one, learned again when one of
        them has outgrown it: every device's archive of an edge process sharing the
        process's words, or a device whose map joined another device's place. Words that
        ``other`` shares already (this one among them) change nothing."""
        source = other.source()
        if source is not self:
            self._shared = source

    def source(self) -> PlaceWords:
        """The words whose vocabulary this archive searches under: its own, or those it
        shares (:meth:`share`)."""
        words = self
        while words._shared is not None:
            words = words._shared
        return words

    def index(self, descriptors: np.ndarray, keyframe_ids: Sequence[int],
              keyframe_descriptors: Sequence[np.ndarray], rows: np.ndarray) -> object:
        """A search index of the archive's points ``descriptors`` ((points, 32) uint8), row r
        the descriptor at ``rows[r]`` of the keyframes' descriptors laid end to end: exact
        below ``exact_below`` points, else the vocabulary's inverted file."""
        import faiss

        vocabulary = self.vocabulary_for(len(descriptors), lambda: descriptors) \
            if len(descriptors) >= self.exact_below else None
        if vocabulary is None:
            index = faiss.IndexBinaryFlat(DESCRIPTOR_BITS)
            if len(descriptors):
                index.add(descriptors)
            return index
        words = np.concatenate([self._words_of(k, d, vocabulary) for k, d in
                                zip(keyframe_ids, keyframe_descriptors, strict=True)])
        self._forget_all_but(set(keyframe_ids))
        return vocabulary.inverted_file(descriptors, words[rows])

    def vocabulary_for(self, points: int, descriptors: Callable[[], np.ndarray]
                       ) -> PlaceVocabulary | None:
        """The vocabulary for an archive of ``points`` points, learned now — from
        ``descriptors()``, the points' descriptors by ascending point id — where there is none
        yet or the archive outgrew it; while another thread learns it, the one there is (or
        None)."""
        source = self.source()
        if source is not self:
            return source.vocabulary_for(points, descriptors)
        current = self.vocabulary
        if current is not None and points < EIGHTFOLD * current.learned_from:
            return current
        if not self._learning.acquire(blocking=False):
            return current
        try:
            current = self.vocabulary         # another thread may have learned it meanwhile
            if current is not None and points < EIGHTFOLD * current.learned_from:
                return current
            serial = 0 if current is None else current.serial + 1
            self.vocabulary = PlaceVocabulary.learn(descriptors(), serial)
            self.learned += 1
            return self.vocabulary
        finally:
            self._learning.release()

    def _words_of(self, kf_id: int, descriptors: np.ndarray, vocabulary: PlaceVocabulary
                  ) -> np.ndarray:
        cached = self._words.get(kf_id)
        if cached is not None and cached[2] is vocabulary and (
                cached[0] is descriptors or np.array_equal(cached[0], descriptors)):
            return cached[1]
        words = vocabulary.assign(descriptors)
        with self._cache:
            self._words[kf_id] = (descriptors, words, vocabulary)
        return words

    def _forget_all_but(self, kept: set[int]) -> None:
        """Drop the words of keyframes no longer searched, once the cache holds twice as many
        keyframes as a search does (a view leaves out the newest ones: they come back)."""
        if len(self._words) <= 2 * len(kept):
            return
        with self._cache:
            self._words = {k: v for k, v in self._words.items() if k in kept}
