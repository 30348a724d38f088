"""Which of the process's maps holds a keyframe's place: a bag of visual words for every
keyframe the edge's devices uploaded, scored against a device's newest keyframes before any
point of another map is searched — as ORB-SLAM3's place recognition asks one keyframe
database over every map of its Atlas for candidates, not each map in turn.

Why the merge looks need it: a look searches the points of one other device's map for the
looking device's newest keyframes (3-4 ms, screened:
:class:`~twinslam.slam.back_end.map_merging.MergeFinder`), and the looks took the other maps
in turn. With N other maps, a newcomer's keyframes met its place's map once in N looks, and a
merge needs three detections there: with nine devices over three places instead of six, two
merges came 1-6 slots later. Scored here first, a look goes to the map whose keyframes are
most like the newest ones, and to another only where it scores near that one
(:meth:`KeyFrameDatabase.candidates`) or one look in eight
(:data:`edge_mapper.place_merging.EXPLORE_EVERY`).

The words are a flat vocabulary (:class:`~twinslam.slam.back_end.place_words.
PlaceVocabulary`, faiss' binary k-means) of WORDS words, learned once from the first
descriptors the database receives (SAMPLES_A_WORD a word), of whatever places those are.
Each word is weighed by its inverse document frequency over those keyframes, fixed then, as
DBoW2 fixes its weights when it learns its vocabulary. A keyframe is its tf-idf histogram,
L2-normalised; two keyframes score the cosine of theirs. A thousand words cannot tell a
keyframe from its neighbours (a keyframe's ~1000 features fall in some 600 of them), but they
tell places apart (``bench.keyframe_database``: 449 of 450 frames of three places scored a
keyframe of their own place highest, the other level with another's, under words learned from the
places or another dataset; with 256 or 512 words 13 and 3 did not). Coarse words leave
no inverted file to prune, so a query is scored against every row of one matrix by one
product, whose time grows with the rows. A row is not a keyframe but KEYFRAMES_A_ROW
consecutive uploads of one map, their vectors summed: the question is which map, and a
device's neighbouring uploads are views of one stretch of its place. A look's ranking of
three keyframes took 2.3 ms over 5000 keyframes of 50 maps with a row a keyframe and 14 ms
over 20 000; four a row, 0.42 and 2.9 ms, the places told apart as well (449 of 450 frames;
another place near a frame's own for 27 of them instead of 15) (``bench.keyframe_database
--keyframes-a-row``, one thread; filing ~1 ms a keyframe, its words assigned once). Finer
words in an inverted file (DBoW2's ~10⁶) are what would keep it flat as the maps grow.

Threads: :meth:`KeyFrameDatabase.add` and :meth:`KeyFrameDatabase.forget` only queue what
they are given (the slot thread calls them). The words are assigned by the scoring
(:meth:`KeyFrameDatabase.candidates_of`) and the filing (:meth:`KeyFrameDatabase.file`) on
the one thread that calls them (the merge looks' worker): none of that is the slots' time.
The vocabulary is learned there too, unless ``learn_in_scoring`` is off: the edge learns it
on a thread of its own and offers it (:meth:`KeyFrameDatabase.offer_words`), because learned
by a look's ranking it held that look up — 3.0 s on one core, 5.7 s on a busy host — and a
device coming to a mapped place merged 8–10 slots late, uploading as if alone meanwhile. A
map keeps its newest KEPT_A_MAP keyframes in whole rows, the database as large as the maps.
A keyframe a map culls or a copy it adopts is not told: the database is of what each device
uploaded, and only chooses where to look.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from twinslam.slam.back_end.place_words import SAMPLES_A_WORD, PlaceVocabulary

#: the vocabulary's words (fewer told places apart less often: ``bench.keyframe_database``)
WORDS = 1024
#: descriptors the vocabulary is learned from: enough for faiss' k-means (it warns under 39
#: a word), about forty keyframes'
LEARN_FROM = SAMPLES_A_WORD * WORDS
#: a map is a candidate where its best keyframe scores at least this share of the best map's
#: (``bench.keyframe_database`` prints how often another place comes this near)
CANDIDATE_SHARE = 0.9
#: rows the matrix starts with (it doubles as it fills)
FIRST_ROWS = 64
#: a map's consecutive keyframes summed into one row of the matrix: a look asks which map a
#: place is in, not which keyframe, and neighbouring uploads are views of one stretch of it.
#: Four a row scores a quarter of the rows (the ranking's time is the product over them) and
#: told the three places apart as well as one a row; eight a row told them apart less well
#: (``bench.keyframe_database --keyframes-a-row``)
KEYFRAMES_A_ROW = 4
#: each map's newest keyframes' own vectors kept, for the looks' queries
#: (:meth:`KeyFrameDatabase.scores_of`: a look ranks its device's newest uploads)
RECENT_KEPT = 16
#: a map's newest filed keyframes kept (in whole rows: its oldest row given to its next
#: keyframes past it): the edge's map keeps as many (its archive 500 by default, its slice a
#: few dozen), and the database stays as large as the maps, not the session
KEPT_A_MAP = 512


@dataclass
class _MapRows:
    """One map's rows in the matrix, oldest first (the last one open: filling), and which
    row each of its kept keyframes went into."""

    owner: int                                   #: the map's number in the owner column
    rows: list[int] = field(default_factory=list)
    open_sum: np.ndarray | None = None           #: the open row's keyframes' vectors, summed
    open_count: int = 0
    members: dict[int, int] = field(default_factory=dict)
    #: the newest keyframes' own vectors (the looks' queries), oldest first
    recent: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class WeightedWords:
    """A vocabulary and its words' weights (inverse document frequency over the keyframes it
    was learned from)."""

    vocabulary: PlaceVocabulary
    weights: np.ndarray          #: (words,) float32

    @classmethod
    def learn(cls, keyframes: Sequence[np.ndarray], words: int = WORDS, seed: int = 0
              ) -> WeightedWords:
        """Words learned from the descriptors of ``keyframes`` ((n, 32) uint8 each), weighed
        by how few of them each word occurs in."""
        vocabulary = PlaceVocabulary.learn(np.concatenate(keyframes), seed=seed, words=words)
        occurs = np.zeros(words, dtype=np.int64)
        for descriptors in keyframes:
            occurs[np.unique(vocabulary.assign(descriptors))] += 1
        weights = np.log(len(keyframes) / np.maximum(occurs, 1)).astype(np.float32)
        return cls(vocabulary, weights)

    def vectors(self, keyframes: Sequence[np.ndarray]) -> np.ndarray:
        """Each of ``keyframes``' tf-idf histogram over the words, L2-normalised (zeros: no
        words), a row each: their words assigned in one search."""
        words = self.vocabulary.words
        sizes = [len(d) for d in keyframes]
        if not keyframes:
            return np.zeros((0, words), dtype=np.float32)
        assigned = self.vocabulary.assign(np.concatenate(keyframes))
        rows = np.repeat(np.arange(len(keyframes)), sizes)
        counts = np.bincount(rows * words + assigned, minlength=len(keyframes) * words)
        weighed: np.ndarray = counts.reshape(len(keyframes), words).astype(np.float32) \
            * self.weights
        norms = np.linalg.norm(weighed, axis=1, keepdims=True)
        return weighed / np.where(norms > 0, norms, 1.0).astype(np.float32)


class KeyFrameDatabase:
    """Every device's uploaded keyframes as bags of words, by map, to tell which maps a new
    keyframe's place is likely in (:meth:`candidates`)."""

    def __init__(self, learn_from: int = LEARN_FROM, words: int = WORDS,
                 share: float = CANDIDATE_SHARE, kept_a_map: int = KEPT_A_MAP,
                 keyframes_a_row: int = KEYFRAMES_A_ROW) -> None:
        if keyframes_a_row < 1:
            raise ValueError(f"keyframes_a_row={keyframes_a_row}: at least one keyframe a row")
        self.learn_from = learn_from
        self.word_count = words
        self.share = share
        self.kept_a_map = kept_a_map
        self.keyframes_a_row = keyframes_a_row
        #: rows a map keeps: its newest kept_a_map keyframes, in whole rows
        self.rows_a_map = max(-(-kept_a_map // keyframes_a_row), 1)
        self.words: WeightedWords | None = None
        self._queue: list[tuple[str, int | None, np.ndarray | None]] = []
        self._queue_lock = threading.Lock()
        #: keyframes received before the vocabulary was learned: what it is learned from
        self._unfiled: list[tuple[str, int, np.ndarray]] = []
        #: their descriptors, counted under the queue's lock (:meth:`can_learn`)
        self._unfiled_descriptors = 0
        #: the scoring learns the words once enough descriptors arrived; False: it waits for
        #: words learned on another thread (:meth:`offer_words`), which the edge does
        self.learn_in_scoring = True
        #: words learned on another thread, taken by the next scoring or filing
        self._offered: WeightedWords | None = None
        #: every map's rows (keyframes_a_row consecutive keyframes' vectors summed and
        #: L2-normalised, a row) in one matrix: one product scores a query against every
        #: map; a forgotten map's rows are owned by none (-1) and free for the next keyframes
        self._matrix = np.zeros((FIRST_ROWS, words), dtype=np.float32)
        self._owner = np.full(FIRST_ROWS, -1, dtype=np.int64)
        self._used = 0
        self._free: list[int] = []
        self._map_index: dict[str, int] = {}
        self._maps: dict[str, _MapRows] = {}

    def add(self, map_name: str, kf_id: int, descriptors: np.ndarray) -> None:
        """Keyframe ``kf_id`` of ``map_name`` (its (n, 32) uint8 ORB descriptors), filed at the
        next scoring into the map's open row; a keyframe the map holds already is filed
        once."""
        with self._queue_lock:
            self._queue.append((map_name, kf_id, descriptors))

    def forget(self, map_name: str) -> None:
        """Every keyframe of ``map_name`` dropped at the next scoring (its device starts a new
        map), those added after this call kept."""
        with self._queue_lock:
            self._queue.append((map_name, None, None))

    def queued(self) -> int:
        """Keyframes and forgettings waiting for the next scoring (or :meth:`file`)."""
        with self._queue_lock:
            return len(self._queue)

    def can_learn(self) -> bool:
        """Whether the words are not learned (nor offered) yet and enough descriptors wait to
        learn them from: a :meth:`file` now learns them, or a thread of its own from
        :meth:`learning_sample`, as the edge does while its first devices walk. Left to the
        first scoring, the learning (3.0 s on one core for the default words, more on a busy
        host) delayed live merges by several slots, the look that scored waiting for it
        (docs/results/shared-map.md, "The words learned beside the looks")."""
        with self._queue_lock:
            if self.words is not None or self._offered is not None:
                return False
            waiting = self._unfiled_descriptors + sum(
                len(d) for _, _, d in self._queue if d is not None)
        return waiting >= max(self.learn_from, self.word_count)

    def learning_sample(self) -> list[np.ndarray]:
        """The descriptors the words would be learned from now (each waiting keyframe's:
        filed before the words, then queued, in the order they arrived), for a thread of its
        own to learn them from (:meth:`WeightedWords.learn`, then :meth:`offer_words`)."""
        with self._queue_lock:
            return [d for _, _, d in self._unfiled] + [
                d for _, kf_id, d in self._queue if kf_id is not None and d is not None
                and len(d)]

    def offer_words(self, words: WeightedWords) -> None:
        """Words learned on another thread, for the next scoring or filing to take (on the
        scoring thread: the matrix is that thread's) and file what waited under them;
        ignored where the database has words."""
        with self._queue_lock:
            if self.words is None:
                self._offered = words

    def file(self) -> None:
        """File what was queued now (on the scoring thread): where no look scores for a
        while — every device of the edge in one place, or one device alone — the queue
        would keep every upload's descriptors. Learns the words where enough descriptors
        arrived and none were offered, unless ``learn_in_scoring`` is off: the edge's words
        come from a thread of their own, and a filing that learned them too ran the same
        k-means a second time on the looks' worker (a fifty-device edge's filing took 15 % of
        its samples)."""
        self._file(self.learn_in_scoring)

    @property
    def rows(self) -> int:
        """Rows the matrix uses: every map's (a row a keyframes_a_row keyframes), and those a
        forgotten map left free."""
        return self._used

    def keyframes(self, map_name: str) -> int:
        """The keyframes of ``map_name`` filed (under words) and kept."""
        kept = self._maps.get(map_name)
        return len(kept.members) if kept is not None else 0

    def scores(self, queries: Sequence[np.ndarray], maps: Sequence[str]) -> dict[str, float]:
        """Each of ``maps``' best cosine score with any of ``queries`` (descriptor arrays),
        after filing what was queued; empty while there are no words yet."""
        self._file(self.learn_in_scoring)
        present = [q for q in queries if len(q)]
        if self.words is None or not present:
            return {}
        return self._best(self.words.vectors(present), maps)

    def scores_of(self, map_name: str, kf_ids: Sequence[int], maps: Sequence[str]
                  ) -> dict[str, float]:
        """:meth:`scores` of keyframes ``kf_ids`` of ``map_name`` as they were filed (a
        look's queries are its device's newest uploads: their words are assigned once, when
        filed, not again to rank them); empty where none of them is among the map's
        :data:`RECENT_KEPT` newest."""
        self._file(self.learn_in_scoring)
        kept = self._maps.get(map_name)
        picked = [kept.recent[k] for k in kf_ids if k in kept.recent] if kept else []
        return self._best(np.stack(picked), maps) if picked else {}

    def candidates(self, queries: Sequence[np.ndarray], maps: Sequence[str]) -> list[str]:
        """The maps among ``maps`` worth looking in for ``queries``' place, best first: the
        best-scoring one and those within :attr:`share` of its score. Empty where nothing
        scores (no words yet, no keyframes filed for ``maps``): the caller has no ranking."""
        return self._ranked(self.scores(queries, maps))

    def candidates_of(self, map_name: str, kf_ids: Sequence[int], maps: Sequence[str]
                      ) -> list[str]:
        """:meth:`candidates` for keyframes ``kf_ids`` of ``map_name`` as they were filed."""
        return self._ranked(self.scores_of(map_name, kf_ids, maps))

    def _ranked(self, scores: dict[str, float]) -> list[str]:
        best = max(scores.values(), default=0.0)
        if best <= 0.0:
            return []
        return sorted((m for m, s in scores.items() if s >= self.share * best),
                      key=lambda m: -scores[m])

    def _best(self, vectors: np.ndarray, maps: Sequence[str]) -> dict[str, float]:
        """Each of ``maps``' best score with any of ``vectors`` (rows): one product over
        every map's rows, then the best row of each map."""
        if not self._used:
            return {}
        best_row = (self._matrix[:self._used] @ vectors.T).max(axis=1)
        owner = self._owner[:self._used]
        kept = owner >= 0
        best = np.zeros(len(self._map_index))
        np.maximum.at(best, owner[kept], best_row[kept])
        return {m: float(best[self._maps[m].owner]) for m in maps
                if m in self._maps and self._maps[m].members}

    def _file(self, learn: bool = True) -> None:
        """What was queued, filed under the words: words learned on another thread and
        offered (:meth:`offer_words`) taken first, else — with ``learn`` — learned here
        once enough descriptors arrived."""
        with self._queue_lock:
            queued, self._queue = self._queue, []
            for map_name, kf_id, descriptors in queued:
                if kf_id is None:
                    gone = self._maps.pop(map_name, None)
                    for row in gone.rows if gone is not None else []:
                        self._owner[row] = -1
                        self._free.append(row)
                    self._unfiled = [u for u in self._unfiled if u[0] != map_name]
                elif descriptors is not None and len(descriptors):
                    self._unfiled.append((map_name, kf_id, descriptors))
            self._unfiled_descriptors = sum(len(d) for _, _, d in self._unfiled)
            if self.words is None and self._offered is not None:
                self.words, self._offered = self._offered, None
        if self.words is None:
            if not learn or self._unfiled_descriptors < max(self.learn_from, self.word_count):
                return                              # k-means needs a point a word, at least
            self.words = WeightedWords.learn([d for _, _, d in self._unfiled],
                                             self.word_count)
        with self._queue_lock:
            unfiled, self._unfiled = self._unfiled, []
            self._unfiled_descriptors = 0
        if unfiled:
            vectors = self.words.vectors([d for _, _, d in unfiled])
            for (map_name, kf_id, _), vector in zip(unfiled, vectors, strict=True):
                self._put(map_name, kf_id, vector)

    def _put(self, map_name: str, kf_id: int, vector: np.ndarray) -> None:
        """``vector`` into ``map_name``'s open row (a new one once it holds keyframes_a_row
        keyframes), and among the map's newest keyframes' own vectors."""
        kept = self._maps.get(map_name)
        if kept is None:
            owner = self._map_index.setdefault(map_name, len(self._map_index))
            kept = self._maps[map_name] = _MapRows(owner)
        if kf_id in kept.members:
            return
        if kept.open_sum is None or kept.open_count >= self.keyframes_a_row:
            kept.rows.append(self._next_row(kept))
            kept.open_sum = np.zeros(self.word_count, dtype=np.float32)
            kept.open_count = 0
        row = kept.rows[-1]
        kept.open_sum += vector
        kept.open_count += 1
        kept.members[kf_id] = row
        norm = float(np.linalg.norm(kept.open_sum))
        self._matrix[row] = kept.open_sum / norm if norm > 0 else kept.open_sum
        self._owner[row] = kept.owner
        kept.recent[kf_id] = vector
        if len(kept.recent) > RECENT_KEPT:
            del kept.recent[next(iter(kept.recent))]

    def _next_row(self, kept: _MapRows) -> int:
        """A row for ``kept``'s next keyframes: its oldest one where it holds its bound (its
        keyframes leave it), a forgotten map's, or a new one."""
        if len(kept.rows) >= self.rows_a_map:
            row = kept.rows.pop(0)
            kept.members = {k: r for k, r in kept.members.items() if r != row}
            return row
        if self._free:
            return self._free.pop()
        if self._used == len(self._matrix):
            self._matrix = np.concatenate([self._matrix, np.zeros_like(self._matrix)])
            self._owner = np.concatenate([self._owner, np.full_like(self._owner, -1)])
        self._used += 1
        return self._used - 1
