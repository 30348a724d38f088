"""The edge's archive of evicted keyframes: place recognition over it on real ORB features of
the synthetic room, the capacity (least recently useful first), and its files on disk."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from twinslam.sequences.frame import Sequence
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.front_end.orb_extractor import OrbExtractor


def _keyframe(kf_id: int, descriptors: np.ndarray, first_point: int, slot: int = 0
              ) -> ArchivedKeyFrame:
    n = len(descriptors)
    pose = np.eye(4)
    pose[0, 3] = 0.01 * kf_id
    return ArchivedKeyFrame(kf_id, pose, np.arange(first_point, first_point + n),
                            np.full((n, 3), float(kf_id)), descriptors,
                            np.full((n, 3), 1.5), slot)


def _random_keyframe(kf_id: int, slot: int, n: int = 50) -> ArchivedKeyFrame:
    rng = np.random.default_rng(kf_id)
    return _keyframe(kf_id, rng.integers(0, 256, (n, 32), dtype=np.uint8), 1000 * kf_id + 1,
                     slot)


def _room_archive(every: int) -> tuple[KeyFrameArchive, Sequence, OrbExtractor]:
    """Keyframes every ``every`` frames of the synthetic room's 300-frame walk, each with its
    own points; (the archive, the walk, the extractor)."""
    seq = open_sequence("synthetic:300", 0, 300)
    orb = OrbExtractor()
    archive = KeyFrameArchive(100)
    first = 1
    for slot, frame in enumerate(range(0, 300, every)):
        desc = orb.extract(seq.read(frame).color).descriptors
        archive.add(_keyframe(frame, desc, first, slot))
        first += len(desc)
    return archive, seq, orb


def test_a_revisited_place_is_recognised_among_the_archived_keyframes() -> None:
    """Keyframes every 30 frames of the room's walk: a frame a few frames past one of them
    votes for it first; descriptors of no place vote for nothing."""
    archive, seq, orb = _room_archive(30)
    for query, place in ((3, 0), (123, 120), (243, 240)):
        found = archive.recognise(orb.extract(seq.read(query).color).descriptors)
        assert found and found[0][0] == place, (query, found)
        assert len(found) <= 3 and all(votes > 0 for _, votes in found)
        assert found[0][1] > 2 * found[1][1] if len(found) > 1 else True, found
    noise = np.random.default_rng(0).integers(0, 256, (1000, 32), dtype=np.uint8)
    assert archive.recognise(noise) == []
    assert archive.recognise(np.zeros((0, 32), np.uint8)) == []
    with pytest.raises(ValueError, match=r"\(n, 32\) uint8"):
        archive.recognise(np.zeros((10, 16), np.uint8))


def test_a_descriptor_votes_against_the_nearest_other_point_not_another_view_of_its_own(
        ) -> None:
    """The ratio test's runner-up is the nearest *other* map point: two keyframes that saw the
    same point do not cancel its vote — each of them gets it — two different points alike do.
    An archive of one point has no runner-up."""
    rng = np.random.default_rng(5)
    seen = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    archive = KeyFrameArchive(10)
    archive.add(_keyframe(1, seen.copy(), 7))
    assert archive.recognise(seen) == [(1, 1)]                # one point: no runner-up
    archive.add(_keyframe(2, seen.copy(), 7))                 # the same point, seen again
    assert archive.recognise(seen) == [(1, 1), (2, 1)]
    archive.add(_keyframe(3, seen.copy(), 99))                # another point, alike
    assert archive.recognise(seen) == []


def test_a_point_many_keyframes_saw_still_faces_the_ratio_test() -> None:
    """However many keyframes observed a point, an alike other point still makes its match
    ambiguous: indexed by observation, ten copies of the point filled the nearest rows and the
    ratio test went unasked."""
    rng = np.random.default_rng(6)
    seen = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    point, lookalike = seen.copy(), seen.copy()
    point[0, 0] ^= 0b11                       # the query two bits from the point …
    lookalike[0, 1] ^= 0b11                   # … and two from another one
    archive = KeyFrameArchive(20)
    for kf_id in range(1, 11):
        archive.add(_keyframe(kf_id, point.copy(), 7))
    assert archive.recognise(seen, top=20) == [(k, 1) for k in range(1, 11)]
    archive.add(_keyframe(11, lookalike, 99))
    assert archive.recognise(seen) == []


def test_recognition_ranks_only_the_keyframes_it_may_propose() -> None:
    """A loop looks among the old walk only: the recent keyframes, which share the most with a
    new one, are not ranked, so they cannot crowd the old place out of the candidates."""
    archive, seq, orb = _room_archive(10)
    desc = orb.extract(seq.read(245).color).descriptors
    everyone = archive.recognise(desc, top=3)
    assert everyone[0][0] in (240, 250), everyone
    old = archive.recognise(desc, top=3, eligible=lambda k: k < 100)
    assert old and all(k < 100 for k, _ in old), old
    assert archive.recognise(desc, eligible=lambda k: False) == []


def test_past_its_capacity_the_least_recently_useful_keyframe_leaves() -> None:
    archive = KeyFrameArchive(3)
    assert [archive.add(_random_keyframe(k, slot=k)) for k in (1, 2, 3)] == [[], [], []]
    archive.touch([1], slot=10)                   # recognised lately: it stays
    assert archive.add(_random_keyframe(4, slot=4)) == [2]
    assert sorted(kf.id for kf in archive) == [1, 3, 4] and len(archive) == 3
    assert archive.nbytes == sum(kf.nbytes for kf in archive) == 3 * (50 * 88 + 128)
    taken = archive.take(3)                       # restored into the managed map
    assert taken.id == 3 and 3 not in archive and len(archive) == 2
    with pytest.raises(ValueError, match="archived already"):
        archive.add(_random_keyframe(1, slot=11))
    forgetful = KeyFrameArchive(0)
    assert forgetful.add(_random_keyframe(5, slot=5)) == [5] and len(forgetful) == 0
    with pytest.raises(ValueError, match="0 or more"):
        KeyFrameArchive(-1)


def test_the_archive_on_disk_comes_back_and_an_unreadable_file_is_named(
        tmp_path: Path) -> None:
    """One file an archived keyframe, removed when it leaves; read back in archival order, a
    keyframe the managed map holds again dropped, an unreadable file skipped and named."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(3, folder)
    for k in (1, 2, 3, 4):
        archive.add(_random_keyframe(k, slot=k))
    assert sorted(p.name for p in folder.iterdir()) == [
        f"keyframe-{k:09d}.npz" for k in (2, 3, 4)]
    (folder / "keyframe-000000009.npz").write_bytes(b"not an archived keyframe")
    again, problems = KeyFrameArchive.restore(3, folder, in_map={3})
    assert sorted(kf.id for kf in again) == [2, 4]
    assert not (folder / "keyframe-000000003.npz").exists()
    assert len(problems) == 1 and "keyframe-000000009.npz" in problems[0]
    kept = again.get(4)
    original = _random_keyframe(4, slot=4)
    for name in ("pose", "point_ids", "positions", "descriptors", "measurements"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(original, name))
    assert kept.archived_slot == 4
    # a keyframe taken back keeps its file until the map holding it is checkpointed
    again.take(2)
    assert (folder / "keyframe-000000002.npz").exists()
    again.release_taken()
    assert not (folder / "keyframe-000000002.npz").exists()
    smaller, _ = KeyFrameArchive.restore(1, folder)
    assert [kf.id for kf in smaller] == [4]       # the capacity holds after a restart too
    empty, problems = KeyFrameArchive.restore(3, tmp_path / "none")
    assert len(empty) == 0 and problems == []


def test_a_keyframe_taken_back_and_archived_again_keeps_its_file(tmp_path: Path) -> None:
    """A keyframe restored into the map and evicted again before the map's next checkpoint is
    archived again under the same file: the checkpoint's release must not delete it (it did:
    with ``checkpoint_every`` above 1 a restart found the keyframe in neither the map nor the
    archive)."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(3, folder)
    archive.add(_random_keyframe(7, slot=1))
    back = archive.take(7)
    archive.add(dataclasses.replace(back, archived_slot=2))     # evicted again
    archive.release_taken()                                     # the map's checkpoint
    assert (folder / "keyframe-000000007.npz").exists()
    again, problems = KeyFrameArchive.restore(3, folder)
    assert [kf.id for kf in again] == [7] and again.get(7).archived_slot == 2 and not problems


def test_a_checkpoint_releases_only_the_files_of_keyframes_its_map_holds(
        tmp_path: Path) -> None:
    """Written off the slot thread, a checkpoint lands slots after its arrays were gathered:
    the files it releases are those of keyframes its own map holds and the archive does not
    hold again by then."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    for k in (1, 2, 3):
        archive.add(_random_keyframe(k, slot=k))
    for k in (1, 2, 3):
        archive.take(k)
    taken = archive.hand_over_taken()
    assert taken == {1, 2, 3} and archive.hand_over_taken() == frozenset()
    archive.add(_random_keyframe(3, slot=5))         # archived again before the write landed
    # the checkpoint that landed holds 1 and 3 in its map; 2 it holds archived (it replaced
    # the checkpoint that took 2: a restart from it finds 2 in the archive only)
    archive.release(taken, in_map=np.array([1, 3]))
    assert sorted(p.name for p in folder.iterdir()) == [
        "keyframe-000000002.npz", "keyframe-000000003.npz"]


def test_an_archive_written_later_owes_each_file_until_the_checkpoints_writer_lands_it(
        tmp_path: Path) -> None:
    """With the checkpoint writer (``checkpoint_in_background``), archiving writes no file on
    the slot thread: each is owed until the writer lands it before the map checkpoint — moved
    there as a loop moved it meanwhile, as it was archived where the map took it back (the
    checkpoint about to land may predate that), and not at all where the archive let it go
    for good (a late write would bring a forgotten keyframe's file back)."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(3, folder)
    archive.write_later = True
    for k in (1, 2, 3, 4):                            # 1 leaves to keep the capacity
        archive.add(_random_keyframe(k, slot=k))
    taken = archive.take(3)
    assert archive.correct({2: _lift(0.05)}) == [2]
    archive.drop(4)                                   # gone for good
    assert not list(folder.glob("keyframe-*")) and archive.owed == 2
    assert archive.write_owed() == 2 and archive.owed == 0
    assert sorted(p.name for p in folder.glob("keyframe-*")) == [
        "keyframe-000000002.npz", "keyframe-000000003.npz"]
    back, problems = KeyFrameArchive.restore(3, folder)
    assert problems == [] and sorted(kf.id for kf in back) == [2, 3]
    np.testing.assert_allclose(back.get(2).pose, archive.get(2).pose, atol=1e-12)
    np.testing.assert_array_equal(back.get(3).descriptors, taken.descriptors)
    assert archive.write_owed() == 0                  # nothing owed twice
    archive.release(archive.hand_over_taken())        # the map holding 3 checkpointed
    assert not (folder / "keyframe-000000003.npz").exists()


def test_an_owed_file_is_written_without_holding_up_the_slot_thread(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The writer's write (and its fsync) of keyframe 1's file is held up; meanwhile the slot
    thread archives keyframe 3 and drops keyframe 2, whose write was to come — neither waits
    for the disk. Keyframe 2 gets no file (a late write would bring a dropped keyframe back);
    keyframe 1, moved by a loop while its first write was under way, is written again where
    it stands now."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    archive.write_later = True
    for k in (1, 2):
        archive.add(_random_keyframe(k, slot=k))
    writing, release = threading.Event(), threading.Event()
    save = ArchivedKeyFrame.save

    def held_up(kf: ArchivedKeyFrame, path: Path) -> None:
        if kf.id == 1 and not release.is_set():
            writing.set()
            assert release.wait(30.0)
        save(kf, path)

    monkeypatch.setattr(ArchivedKeyFrame, "save", held_up)
    writer = threading.Thread(target=archive.write_owed)
    writer.start()
    assert writing.wait(30.0)
    started = time.monotonic()
    archive.add(_random_keyframe(3, slot=3))
    archive.drop(2)
    assert archive.correct({1: _lift(0.05)}, write=False) == [1]
    assert time.monotonic() - started < 5.0           # not behind the held-up write
    release.set()
    writer.join(30.0)
    assert not writer.is_alive()
    assert sorted(p.name for p in folder.glob("keyframe-*")) == ["keyframe-000000001.npz"]
    cut_short = folder / "keyframe-000000009.npz.owed.tmp"   # an edge stopped mid-write
    cut_short.write_bytes(b"half a file")
    back, problems = KeyFrameArchive.restore(5, folder)
    assert problems == [] and [kf.id for kf in back] == [1] and not cut_short.exists()
    np.testing.assert_allclose(back.get(1).pose, archive.get(1).pose, atol=1e-12)
    assert archive.owed == 1                          # 3: at the next checkpoint


def test_an_owed_file_that_cannot_be_written_stays_owed(tmp_path: Path) -> None:
    """A disk error raises to the writer (which then writes no checkpoint without the file)
    and the keyframe is owed still: the next checkpoint's write tries it again."""
    blocked = tmp_path / "edge.npz.archive"
    blocked.write_text("a file where the archive's folder should be")
    archive = KeyFrameArchive(3, blocked)
    archive.write_later = True
    archive.add(_random_keyframe(1, slot=1))
    with pytest.raises(OSError):
        archive.write_owed()
    assert archive.owed == 1
    blocked.unlink()
    assert archive.write_owed() == 1 and (blocked / "keyframe-000000001.npz").exists()


def _lift(dy: float) -> np.ndarray:
    """A rigid correction: a turn of 5° about the vertical and ``dy`` up."""
    c = np.eye(4)
    a = np.radians(5.0)
    c[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    c[1, 3] = dy
    return c


def test_a_corrected_archive_comes_back_where_its_loops_moved_it_its_files_unwritten(
        tmp_path: Path) -> None:
    """Loops move archived keyframes, pose and points; a restart reads them where the last
    correction left them, from one pose file beside files that were written once."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    for k in (1, 2, 3):
        archive.add(_random_keyframe(k, slot=k))
    written = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert archive.correct({1: _lift(0.05), 2: _lift(0.02)}) == [1, 2]
    assert archive.correct({1: _lift(-0.01)}) == [1]          # a second loop moves 1 again
    assert {p.name: p.read_bytes() for p in folder.glob("keyframe-*")} == written
    again, problems = KeyFrameArchive.restore(5, folder)
    assert problems == []
    for k in (1, 2, 3):
        now, back = archive.get(k), again.get(k)
        np.testing.assert_allclose(back.pose, now.pose, atol=1e-12)
        np.testing.assert_allclose(back.positions, now.positions, atol=1e-12)
        np.testing.assert_array_equal(back.descriptors, now.descriptors)
    assert not np.allclose(again.get(1).pose, _random_keyframe(1, slot=1).pose)
    # the restored archive records them still: its next correction keeps both moves
    assert again.correct({2: _lift(0.03)}) == [2]
    third, _ = KeyFrameArchive.restore(5, folder)
    np.testing.assert_allclose(third.get(1).pose, archive.get(1).pose, atol=1e-12)
    np.testing.assert_allclose(third.get(2).positions, again.get(2).positions, atol=1e-12)


def test_a_keyframe_written_again_after_a_loop_is_read_from_its_newer_file(
        tmp_path: Path) -> None:
    """A moved keyframe taken back into the map keeps its move until the map is checkpointed
    (a restart from the older map finds it in the archive, moved); archived again, its new
    file holds where it stands, and the pose file's older entry is not applied to it."""
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    archive.add(_random_keyframe(4, slot=1))
    archive.correct({4: _lift(0.05)})
    moved = archive.take(4)
    archive.save_poses()                   # another loop's poses written while 4 is taken
    kept, _ = KeyFrameArchive.restore(5, folder)
    np.testing.assert_allclose(kept.get(4).positions, moved.positions, atol=1e-12)
    # evicted again, with the map's own edits of its points, then another keyframe moved
    edited = dataclasses.replace(moved, positions=moved.positions + 0.5, archived_slot=6)
    archive.add(edited)
    archive.add(_random_keyframe(5, slot=6))
    archive.correct({5: _lift(0.02)})
    again, problems = KeyFrameArchive.restore(5, folder)
    assert problems == []
    np.testing.assert_array_equal(again.get(4).positions, edited.positions)
    np.testing.assert_array_equal(again.get(4).pose, edited.pose)


def test_an_unreadable_pose_file_is_named_and_the_files_poses_kept(tmp_path: Path) -> None:
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    archive.add(_random_keyframe(1, slot=1))
    archive.correct({1: _lift(0.05)})
    (folder / "poses.npz").write_bytes(b"not a pose file")
    again, problems = KeyFrameArchive.restore(5, folder)
    assert len(problems) == 1 and "poses.npz" in problems[0]
    np.testing.assert_array_equal(again.get(1).pose, _random_keyframe(1, slot=1).pose)
