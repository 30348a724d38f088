"""Place recognition over a large archive looks under visual words the archive learned from
its own points: it must find the places exact search finds, learn its vocabulary once for
every view the loop closer takes of the archive, and learn it again only once the archive
outgrew it."""

from __future__ import annotations

import numpy as np

from tests.test_archive_relocalisation import room  # noqa: F401 (the archived room fixture)
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.loop_detection import detect_loop
from twinslam.slam.back_end.place_words import (
    EIGHTFOLD,
    FEWEST_WORDS,
    MOST_WORDS,
    PlaceWords,
    words_for,
)
from twinslam.slam.front_end.orb_extractor import OrbExtractor

Room = tuple[object, KeyFrameArchive, OrbExtractor]


def _worded(archive: KeyFrameArchive, exact_below: int) -> KeyFrameArchive:
    """The same keyframes, searched under words past ``exact_below`` points."""
    worded = KeyFrameArchive(len(archive), words=PlaceWords(exact_below))
    for kf in archive:
        worded.add(kf, write=False)
    return worded


def test_an_archive_searched_under_its_words_finds_the_places_exact_search_finds(
        room: Room) -> None:  # noqa: F811
    """The room's archive (a few thousand points) with words from a thousand points on: every
    frame looking for a loop finds the keyframe exact search finds, its pose within a
    centimetre of exact search's."""
    seq, archive, orb = room
    worded = _worded(archive, exact_below=1000)
    for frame_index in (4, 64, 127, 251):
        frame = seq.read(frame_index)                          # type: ignore[attr-defined]
        feats = orb.extract(frame.color)
        exact = detect_loop(archive, 1000, feats.points, feats.descriptors,
                            seq.intrinsics)                    # type: ignore[attr-defined]
        looked_up = detect_loop(worded.snapshot(), 1000, feats.points, feats.descriptors,
                                seq.intrinsics)                # type: ignore[attr-defined]
        assert exact.found and looked_up.found, looked_up.reason
        assert looked_up.old == exact.old
        assert looked_up.pose is not None and exact.pose is not None
        assert np.linalg.norm(looked_up.pose[:3, 3] - exact.pose[:3, 3]) < 0.01
    assert worded.words.vocabulary is not None and worded.words.learned == 1
    assert archive.words.vocabulary is None            # the room alone is searched exactly


def test_the_vocabulary_is_learned_once_for_every_view_of_the_archive(
        room: Room) -> None:  # noqa: F811
    """The loop closer searches a new view of the archive every job: the views share the
    vocabulary the first one learned (and each keyframe's words) instead of learning
    their own."""
    seq, archive, orb = room
    worded = _worded(archive, exact_below=1000)
    feats = orb.extract(seq.read(64).color)                    # type: ignore[attr-defined]
    ranked = [view.recognise(feats.descriptors) for view in
              (worded.snapshot(), worded.only(lambda k: k < 200), worded.snapshot())]
    assert worded.words.learned == 1
    assert ranked[0] == ranked[2] and ranked[0][0][0] in (60, 30, 90)


def test_the_vocabulary_is_learned_again_once_the_archive_outgrew_it() -> None:
    rng = np.random.default_rng(0)
    descriptors = rng.integers(0, 256, (EIGHTFOLD * 400 + 1, 32), dtype=np.uint8)
    words = PlaceWords(exact_below=100)
    small, grown = descriptors[:400], descriptors

    def index(points: np.ndarray) -> object:
        return words.index(points, [1], [points], np.arange(len(points)))

    index(small)
    first = words.vocabulary
    assert first is not None and first.learned_from == 400 and words.learned == 1
    index(descriptors[:EIGHTFOLD * 400 - 1])                     # not yet outgrown
    assert words.vocabulary is first
    index(grown)
    assert words.learned == 2 and words.vocabulary is not first
    assert words.vocabulary is not None and words.vocabulary.serial == 1


def test_archives_of_one_place_learn_one_vocabulary_and_search_under_it() -> None:
    """A device's archive that shares its place's words learns none of its own: the first
    of the place's archives that needs a vocabulary learns it for all of them, each files its
    keyframes' words under it, and sharing back with a sharer changes nothing."""
    rng = np.random.default_rng(1)
    descriptors = rng.integers(0, 256, (600, 32), dtype=np.uint8)
    root, joined, third = (PlaceWords(exact_below=100) for _ in range(3))
    joined.share(root)
    third.share(joined)                          # through a device that joined the place
    assert third.source() is root and joined.source() is root
    joined.index(descriptors[:400], [7], [descriptors[:400]], np.arange(400))
    assert root.learned == 1 and joined.learned == 0 and joined.vocabulary is None
    learned = root.vocabulary
    third.index(descriptors, [3], [descriptors], np.arange(600))
    assert root.learned == 1 and root.vocabulary is learned and third.learned == 0
    root.share(third)                            # root shares with itself: nothing
    assert root.source() is root
    # a keyframe's words are those of the vocabulary the index is filed under
    alone = PlaceWords(exact_below=100)
    alone.index(descriptors[:400], [7], [descriptors[:400]], np.arange(400))
    assert alone.vocabulary is not learned
    assert joined._words[7][2] is learned and alone._words[7][2] is alone.vocabulary


def test_the_vocabulary_grows_with_the_archive_within_its_bounds() -> None:
    assert words_for(1_000) == FEWEST_WORDS
    assert words_for(100_000) == MOST_WORDS
    assert FEWEST_WORDS < words_for(20_000) < MOST_WORDS


def test_a_search_while_another_thread_learns_the_words_goes_on_exactly() -> None:
    """The loop closer and the merge looks build indexes on threads of their own: while one
    learns the vocabulary (seconds), another must not wait for it nor learn it twice."""
    import faiss

    rng = np.random.default_rng(1)
    descriptors = rng.integers(0, 256, (500, 32), dtype=np.uint8)
    words = PlaceWords(exact_below=100)
    with words._learning:                            # another thread is learning
        index = words.index(descriptors, [1], [descriptors], np.arange(len(descriptors)))
    assert isinstance(index, faiss.IndexBinaryFlat) and words.vocabulary is None
    assert not isinstance(words.index(descriptors, [1], [descriptors],
                                      np.arange(len(descriptors))), faiss.IndexBinaryFlat)
    assert words.learned == 1
