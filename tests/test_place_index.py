"""The loop closer's place index, kept from one job to the next: edited as keyframes come and
go, it must answer every place-recognition question exactly as an index built for the job
would — the same keyframes with the same votes, searched exactly or under the same visual
words — and step aside where it cannot."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.place_words import PlaceWords

#: a world of points, each with the one descriptor its map gave it
POINTS = 6000
#: points a keyframe sees: a window of the walk's points
SEEN = 400


def _world(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (POINTS, 32), dtype=np.uint8)


def _keyframe(kf_id: int, world: np.ndarray, first: int) -> ArchivedKeyFrame:
    """Keyframe ``kf_id`` seeing points ``first``… of the walk (a window that overlaps its
    neighbours'), under the world's descriptors."""
    ids = (np.arange(first, first + SEEN) % POINTS).astype(np.int64)
    n = len(ids)
    return ArchivedKeyFrame(kf_id, np.eye(4), ids, np.zeros((n, 3)), world[ids].copy(),
                            np.zeros((n, 3)), archived_slot=0)


def _noisy(descriptors: np.ndarray, rng: np.random.Generator, bits: int = 12) -> np.ndarray:
    """The descriptors as another frame sees them: ``bits`` bits flipped in each."""
    out = descriptors.copy()
    for row in out:
        for bit in rng.choice(256, bits, replace=False):
            row[bit // 8] ^= np.uint8(1 << (bit % 8))
    return out


def _shared(members: list[ArchivedKeyFrame], kf_id: int) -> dict[int, int]:
    """Each other keyframe's observations of ``kf_id``'s points, counted one by one."""
    own = set(next(kf for kf in members if kf.id == kf_id).point_ids.tolist())
    counts = {kf.id: sum(p in own for p in kf.point_ids.tolist())
              for kf in members if kf.id != kf_id}
    return {k: n for k, n in counts.items() if n}


def _view(members: list[ArchivedKeyFrame], words: PlaceWords,
          index: KeptPlaceIndex | None) -> KeyFrameArchive:
    archive = KeyFrameArchive(len(members), words=words)
    for kf in members:
        archive.add(kf, write=False)
    return archive.only(lambda k: True, index) if index is not None else archive.snapshot()


@pytest.mark.parametrize("exact_below", [10**9, 2000], ids=["exact", "under-words"])
def test_a_kept_index_answers_as_one_built_for_each_job(exact_below: int) -> None:
    """Twelve jobs over a walk: each view gains keyframes at its head, loses some at its tail
    and some in between (restored into the map), and some keyframes come as new objects
    with the same points (the map's, snapshot anew each job). The kept index and an index
    built for each view give the same ranked keyframes and votes, and the same shared
    points; above the threshold both search under the same learned words."""
    world = _world()
    rng = np.random.default_rng(1)
    walk = [_keyframe(kf, world, 150 * kf) for kf in range(40)]
    kept, kept_words, fresh_words = KeptPlaceIndex(), PlaceWords(exact_below), \
        PlaceWords(exact_below)
    low, high = 0, 6
    for _job in range(12):
        low, high = low + int(rng.integers(0, 3)), min(len(walk), high + int(rng.integers(1, 5)))
        members = [kf if rng.random() < 0.7 else ArchivedKeyFrame(**vars(kf))
                   for kf in walk[low:high] if rng.random() > 0.1]
        with_kept, built = _view(members, kept_words, kept), _view(members, fresh_words, None)
        for kf in rng.choice(members, 2):
            seen = _noisy(kf.descriptors[::2], rng)
            query = np.vstack([seen, seen[:50]])     # two features of one corner: two votes
            assert with_kept.recognise(query, top=5) == built.recognise(query, top=5)
            assert with_kept.recognise(query, top=5)[0][0] in {kf.id, kf.id - 1, kf.id + 1}
        probe = members[len(members) // 2].id
        assert with_kept.shared_with(probe) == built.shared_with(probe) == _shared(members,
                                                                                 probe)
        assert kept.points == len(np.unique(np.concatenate([kf.point_ids for kf in members])))
    assert kept.syncs == 12 and kept.declined == 0
    if exact_below < 10**9:
        assert kept_words.vocabulary is not None and fresh_words.vocabulary is not None
        assert np.array_equal(kept_words.vocabulary.assign(world),
                              fresh_words.vocabulary.assign(world))


def test_points_leave_with_their_last_keyframe() -> None:
    """Two keyframes share half their points: the one leaving takes only its own half out,
    and a query for those points no longer finds it."""
    world = _world()
    a, b = _keyframe(1, world, 0), _keyframe(2, world, SEEN // 2)
    kept, words = KeptPlaceIndex(), PlaceWords()
    assert kept.sync({1: a, 2: b}, words) and kept.points == SEEN + SEEN // 2
    assert kept.sync({2: b}, words) and kept.points == SEEN
    view = _view([b], words, kept)
    assert view.recognise(world[: SEEN // 2]) == []          # a's own points: gone
    assert view.recognise(world[SEEN // 2: SEEN])[0][0] == 2


def test_keyframes_that_disagree_on_a_points_descriptor_are_searched_as_before() -> None:
    """A copy of another device's keyframe may hold one of this map's points under its own
    descriptor: the kept index declines, empties itself, and the view builds its own index,
    answering as one built for it."""
    world = _world()
    a, b = _keyframe(1, world, 0), _keyframe(2, world, SEEN // 2)
    other = b.descriptors.copy()
    other[0] ^= 0xFF                                           # point SEEN // 2, disagreed
    b = ArchivedKeyFrame(**{**vars(b), "descriptors": other})
    kept = KeptPlaceIndex()
    with_kept, built = _view([a, b], PlaceWords(), kept), _view([a, b], PlaceWords(), None)
    query = world[SEEN // 4: SEEN // 4 + 200]
    assert with_kept.recognise(query) == built.recognise(query)
    assert kept.declined == 1 and kept.points == 0
    # agreeing keyframes later: the index stays aside (each try would fill it anew first)
    assert not kept.sync({1: a}, PlaceWords()) and kept.points == 0


def test_a_view_searched_after_another_took_the_index_is_answered_for_its_own_keyframes() -> None:
    """Two views share one kept index (a look into a map, then the next look): searching the
    first again after the second synchronised the index answers for the first's keyframes,
    never the second's."""
    world = _world()
    a, b = _keyframe(1, world, 0), _keyframe(2, world, 2 * SEEN)
    kept, words = KeptPlaceIndex(), PlaceWords()
    first, second = _view([a], words, kept), _view([b], words, kept)
    assert first.recognise(world[:SEEN])[0][0] == 1
    assert second.recognise(world[2 * SEEN: 3 * SEEN])[0][0] == 2
    assert first.recognise(world[2 * SEEN: 3 * SEEN]) == []
    assert first.recognise(world[:SEEN])[0][0] == 1


def test_an_index_whose_edit_failed_half_way_starts_afresh(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """faiss failing while the index is edited (a look or a loop job that fails, reported by
    its caller) leaves no half-edited index behind: the next synchronisation fills it anew
    and answers as an index built for it."""
    world = _world()
    a, b = _keyframe(1, world, 0), _keyframe(2, world, SEEN // 2)
    kept, words = KeptPlaceIndex(), PlaceWords()
    assert kept.sync({1: a}, words)

    def broken(self: KeptPlaceIndex, words: PlaceWords) -> None:
        raise RuntimeError("faiss failed")

    with monkeypatch.context() as patch:
        patch.setattr(KeptPlaceIndex, "_file", broken)
        with pytest.raises(RuntimeError):
            kept.sync({1: a, 2: b}, words)
    assert kept.points == 0
    query = world[: SEEN + SEEN // 2]
    assert _view([a, b], words, kept).recognise(query) == \
        _view([a, b], PlaceWords(), None).recognise(query)
