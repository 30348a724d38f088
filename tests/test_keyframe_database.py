"""The process's keyframe database tells which map a keyframe's place is in: a frame of the
room scores the room's map first and a frame of the corridor the corridor's; nothing is
ranked before its words are learned, and those are learned on the thread that scores; a map
forgotten is not ranked until its device uploads again; a word every learning keyframe holds
weighs nothing."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.keyframe_database import (
    KEYFRAMES_A_ROW,
    RECENT_KEPT,
    KeyFrameDatabase,
    WeightedWords,
)
from twinslam.slam.front_end.orb_extractor import OrbExtractor

#: the frames filed as keyframes; the queries lie half way between them
EVERY = 20
FRAMES = 300
#: the tests that learn words test when and on which thread they are learned, not how well
#: the words tell places apart: a vocabulary of 256 words learns in a fraction of the
#: default's seconds of k-means (1024 words: 4-8 s from the room's 30 000 descriptors)
LEARNING_WORDS = 256

#: the module's fixtures (the two places' descriptors, their words: 12 s of CPU) are made
#: once, on one worker, not once on every worker that runs one of its tests
pytestmark = pytest.mark.xdist_group("keyframe-database-places")


@pytest.fixture(scope="module")
def places() -> dict[str, dict[int, np.ndarray]]:
    """The ORB descriptors of every tenth frame of the rendered room and corridor."""
    orb = OrbExtractor()
    out = {}
    for name, spec in (("room", f"synthetic:{FRAMES}"),
                       ("corridor", f"synthetic-corridor:{FRAMES}")):
        sequence = open_sequence(spec)
        out[name] = {i: orb.extract(sequence.read(i).color).descriptors     # type: ignore[attr-defined]
                     for i in range(0, FRAMES, EVERY // 2)}
    return out


@pytest.fixture(scope="module")
def words(places: dict[str, dict[int, np.ndarray]]) -> WeightedWords:
    """Words learned from both places' keyframes, once for the tests that do not learn."""
    return WeightedWords.learn([d for frames in places.values()
                                for i, d in frames.items() if i % EVERY == 0])


def _filed(places: dict[str, dict[int, np.ndarray]], words: WeightedWords) -> KeyFrameDatabase:
    """Both places' keyframes filed, each under its place's map, under ``words``."""
    database = KeyFrameDatabase()
    database.words = words
    for name, frames in places.items():
        for index, descriptors in frames.items():
            if index % EVERY == 0:
                database.add(name, index, descriptors)
    return database


def test_a_frame_scores_the_map_of_its_own_place_first(
        places: dict[str, dict[int, np.ndarray]], words: WeightedWords) -> None:
    """Each frame between two keyframes of a place names that place's map first among the
    candidates: a look goes there before the other place's map."""
    database = _filed(places, words)
    for name, frames in places.items():
        for index, descriptors in frames.items():
            if index % EVERY:
                ranked = database.candidates([descriptors], ["room", "corridor"])
                assert ranked and ranked[0] == name, (name, index, ranked)
    assert database.keyframes("room") == database.keyframes("corridor") == FRAMES // EVERY


def test_nothing_is_ranked_before_the_words_are_learned_on_the_scoring_thread(
        places: dict[str, dict[int, np.ndarray]]) -> None:
    """Adding only queues: the words are learned by the first scoring after enough
    descriptors arrived; before, no map is ranked (the looks take the maps in turn)."""
    room = places["room"]
    database = KeyFrameDatabase(learn_from=sum(len(d) for d in room.values()),
                                words=LEARNING_WORDS)
    database.add("room", 0, room[0])
    assert database.candidates([room[10]], ["room"]) == [] and database.words is None
    for index, descriptors in room.items():
        database.add("room", index, descriptors)
    assert database.words is None                       # queued, not learned in add
    assert database.candidates([room[10]], ["room"]) == ["room"]
    assert database.words is not None and database.keyframes("room") == len(room)


def test_the_database_says_when_its_queue_can_teach_it_the_words(
        places: dict[str, dict[int, np.ndarray]]) -> None:
    """Not before enough descriptors wait (queued, or filed before the words), and not once
    the words are learned: a filing then learns them."""
    room = places["room"]
    database = KeyFrameDatabase(learn_from=sum(len(d) for d in room.values()),
                                words=LEARNING_WORDS)
    frames = list(room.items())
    for index, descriptors in frames[:-1]:
        database.add("room", index, descriptors)
    assert not database.can_learn()
    database.file()                                     # filed, still too few to learn
    assert database.words is None and not database.can_learn()
    database.add("room", *frames[-1])
    assert database.can_learn()
    database.file()
    assert database.words is not None and not database.can_learn()
    assert database.keyframes("room") == len(room)


def test_words_learned_on_another_thread_are_taken_by_the_next_scoring(
        places: dict[str, dict[int, np.ndarray]]) -> None:
    """A database whose scoring does not learn (the edge's) ranks nothing however many
    descriptors wait, and its filing learns nothing either, until words learned from its
    sample are offered: the next scoring takes them and files every waiting keyframe under
    them."""
    room = places["room"]
    database = KeyFrameDatabase(learn_from=sum(len(d) for d in room.values()),
                                words=LEARNING_WORDS)
    database.learn_in_scoring = False
    for index, descriptors in room.items():
        database.add("room", index, descriptors)
    assert database.candidates([room[10]], ["room"]) == [] and database.words is None
    database.file()                 # the edge's filing beside the looks learns nothing either:
    assert database.words is None   # the words' own thread does, once
    assert database.can_learn()
    sample = database.learning_sample()
    assert sum(len(d) for d in sample) == sum(len(d) for d in room.values())
    database.offer_words(WeightedWords.learn(sample, database.word_count))
    assert not database.can_learn()
    assert database.candidates([room[10]], ["room"]) == ["room"]
    assert database.words is not None and database.keyframes("room") == len(room)


def test_a_forgotten_map_is_not_ranked_until_its_device_uploads_again(
        places: dict[str, dict[int, np.ndarray]], words: WeightedWords) -> None:
    """A device served with a new map: the old map's keyframes leave the database; the new
    map's, added after, are ranked."""
    database = _filed(places, words)
    query = places["room"][10]
    assert database.candidates([query], ["room", "corridor"])[0] == "room"
    database.forget("room")
    assert database.candidates([query], ["room", "corridor"]) == ["corridor"]
    assert database.keyframes("room") == 0
    database.add("room", 7, places["room"][0])
    assert database.candidates([query], ["room", "corridor"])[0] == "room"
    # its new keyframe took a row the room left free
    assert database.rows == 2 * -(-(FRAMES // EVERY) // KEYFRAMES_A_ROW)


def test_a_map_keeps_its_newest_keyframes_only(
        places: dict[str, dict[int, np.ndarray]], words: WeightedWords) -> None:
    """Past its bound a map's next keyframe takes its oldest one's row: the database grows
    with the maps, not with the session, and what it knows of a map is where it went last."""
    database = KeyFrameDatabase(kept_a_map=3, keyframes_a_row=1)
    database.words = words
    room = places["room"]
    for index, descriptors in room.items():
        database.add("room", index, descriptors)
    database.file()
    assert database.queued() == 0 and database.keyframes("room") == 3
    assert database.rows == 3                      # the rows were given on, not added
    newest = max(room)
    assert database.scores([room[newest]], ["room"])["room"] == pytest.approx(1.0, abs=1e-5)
    assert database.scores([room[0]], ["room"])["room"] < 0.99     # its first left


def test_a_maps_consecutive_keyframes_share_a_row_and_its_newest_are_queries(
        places: dict[str, dict[int, np.ndarray]], words: WeightedWords) -> None:
    """Four consecutive uploads of a map are one row (the ranking's product is over the
    rows); past its bound a map gives its oldest row, with its keyframes, to the next ones;
    a look's queries are the map's newest keyframes, their own vectors kept."""
    database = KeyFrameDatabase(kept_a_map=8, keyframes_a_row=4)
    database.words = words
    room = sorted(places["room"].items())                # 30 frames, every tenth
    for index, descriptors in room[:8]:
        database.add("room", index, descriptors)
    database.file()
    assert database.rows == 2 and database.keyframes("room") == 8     # 4 + 4
    database.add("room", room[8][0], room[8][1])
    database.file()
    # the ninth opens a row past the bound: the oldest row and its four keyframes leave
    assert database.rows == 2 and database.keyframes("room") == 5
    for index, descriptors in room[9:]:
        database.add("room", index, descriptors)
    database.file()
    # 30 keyframes in rows of four; the bound (8) keeps the newest two rows: 4 + 2
    assert database.rows == 2 and database.keyframes("room") == 6
    newest = [index for index, _ in room[-3:]]
    mine = database.scores_of("room", newest, ["room"])["room"]
    assert mine == pytest.approx(database.scores([d for _, d in room[-3:]], ["room"])["room"],
                                 abs=1e-5)
    assert 0.5 < mine < 1.0             # a row of several keyframes, not the query's own
    assert database.scores_of("room", [room[-RECENT_KEPT - 1][0]], ["room"]) == {}
    with pytest.raises(ValueError, match="at least one keyframe a row"):
        KeyFrameDatabase(keyframes_a_row=0)


def test_a_word_every_learning_keyframe_holds_weighs_nothing() -> None:
    """A word in every keyframe the vocabulary was learned from tells no keyframe from
    another (its inverse document frequency is zero); a word in one of them weighs most."""
    rng = np.random.default_rng(0)

    def cluster(n: int) -> np.ndarray:
        """``n`` descriptors a few bits from one drawn at random: one word's worth."""
        base = np.unpackbits(rng.integers(0, 256, 32, dtype=np.uint8))
        flips = rng.random((n, 256)) < 0.02
        return np.packbits(base ^ flips, axis=1)

    common = cluster(50 * 8)
    keyframes = [np.concatenate([common[50 * i:50 * (i + 1)], cluster(50)]) for i in range(8)]
    words = WeightedWords.learn(keyframes, words=12)
    everywhere = int(words.vocabulary.assign(common[:1])[0])
    assert words.weights[everywhere] == 0.0
    assert words.weights.max() == pytest.approx(np.log(8.0))
    vector = words.vectors(keyframes[:1])[0]
    assert vector[everywhere] == 0.0 and np.linalg.norm(vector) == pytest.approx(1.0)
