"""The decoded-frame cache (``TWINSLAM_FRAME_CACHE``): a folder played again gives the same
frames without decoding them; a file rewritten in place is decoded anew however its timestamps
look; a broken entry, a full cache, an unwritable one or a corrupt image cost a decode, never
a wrong frame; a bad bound is refused."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from twinslam.sequences import folders, synthetic
from twinslam.sequences.decoded_frames import (
    BOUND_ENV,
    CACHE_ENV,
    PARTIAL,
    STALE_PARTIAL_S,
    SUFFIX,
    DecodedFrameCache,
)
from twinslam.sequences.frame import RandomAccessSequence, Sequence, SequenceError
from twinslam.sequences.opening import open_sequence

H, W = 48, 64
DEPTH_K = np.array([[70.0, 0, 32], [0, 70.0, 24], [0, 0, 1]])
COLOUR_K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])


def _seven_scenes_folder(root: Path, frames: int = 3) -> Path:
    """A 7-Scenes folder of random colour and a depth ramp, lossless (PNG) both."""
    root.mkdir()
    np.savetxt(root / "camera-intrinsics.txt", DEPTH_K)
    for i in range(frames):
        _write_frame(root, i, seed=i)
        np.savetxt(root / f"frame-{i:06d}.pose.txt", np.eye(4))
    return root


def _write_frame(root: Path, i: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    cv2.imwrite(str(root / f"frame-{i:06d}.color.png"),
                rng.integers(0, 255, (H, W, 3), dtype=np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 0])
    depth = 1000 + 10 * np.arange(W, dtype=np.uint16)[None, :] + rng.integers(0, 9, (H, 1))
    cv2.imwrite(str(root / f"frame-{i:06d}.depth.png"), depth.astype(np.uint16))


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    where = tmp_path / "cache"
    monkeypatch.setenv(CACHE_ENV, str(where))
    monkeypatch.delenv(BOUND_ENV, raising=False)
    return where


def _opened(folder: Path, colour: np.ndarray | None = COLOUR_K) -> Sequence:
    """The folder as the player opens it: through the cache the environment names."""
    return open_sequence(folder, colour_intrinsics=colour,
                         frame_cache=DecodedFrameCache.from_environment())


def _frames(folder: Path, colour: np.ndarray | None = COLOUR_K) -> list:
    return list(_opened(folder, colour))


def _decoding_forbidden(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object) -> None:
        raise AssertionError("decoded although the frame was in the cache")
    monkeypatch.setattr(folders.cv2, "imread", refuse)


def _assert_same(got: list, want: list) -> None:
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.color, b.color) and a.color.dtype == np.uint8
        assert np.array_equal(a.depth, b.depth) and a.depth.dtype == np.float32
        assert (a.index, a.stamp, a.name) == (b.index, b.stamp, b.name)
        assert np.array_equal(a.intrinsics, b.intrinsics)


def test_a_folder_played_again_gives_the_same_frames_without_decoding(
        tmp_path: Path, cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven")
    decoded = list(open_sequence(folder, colour_intrinsics=COLOUR_K))   # no cache: the truth
    assert not cache_dir.exists(), "a reader not given the cache wrote to it"
    first = _frames(folder)
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 3
    _decoding_forbidden(monkeypatch)
    again = _frames(folder)
    _assert_same(first, decoded)
    _assert_same(again, decoded)
    # read backwards and by position too, as a revisit scenario reads
    sequence = _opened(folder)
    assert isinstance(sequence, RandomAccessSequence)
    _assert_same([sequence.read(i) for i in (2, 0)], [decoded[2], decoded[0]])


def test_other_cameras_are_other_entries(tmp_path: Path, cache_dir: Path) -> None:
    """The depth registered to the colour camera and the raw depth differ: neither may be
    answered with the other."""
    folder = _seven_scenes_folder(tmp_path / "seven", frames=1)
    registered = _frames(folder)[0]
    raw = _frames(folder, colour=None)[0]
    assert not np.array_equal(registered.depth, raw.depth)
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 2
    assert np.array_equal(_frames(folder)[0].depth, registered.depth)
    assert np.array_equal(_frames(folder, colour=None)[0].depth, raw.depth)


def test_an_image_rewritten_in_place_is_decoded_anew(tmp_path: Path, cache_dir: Path) -> None:
    """Same name, same size, its timestamps put back: the entry is named by the bytes."""
    folder = _seven_scenes_folder(tmp_path / "seven", frames=1)
    before = _frames(folder)[0]
    colour = folder / "frame-000000.color.png"
    stat = colour.stat()
    image = cv2.imread(str(colour))
    image[0, 0] = 255 - image[0, 0]
    cv2.imwrite(str(colour), image, [cv2.IMWRITE_PNG_COMPRESSION, 0])   # stored: same size
    os.utime(colour, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert colour.stat().st_size == stat.st_size
    after = _frames(folder)[0]
    assert not np.array_equal(after.color, before.color)
    assert np.array_equal(after.color[0, 0], image[0, 0, ::-1])      # BGR on disk, RGB read


def test_a_broken_entry_is_removed_and_the_frame_decoded_again(
        tmp_path: Path, cache_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven", frames=1)
    want = _frames(folder)
    (entry,) = cache_dir.glob(f"*{SUFFIX}")
    entry.write_bytes(entry.read_bytes()[:1000])               # a writer killed half-way
    with caplog.at_level(logging.WARNING):
        got = _frames(folder)
    _assert_same(got, want)
    assert "unreadable" in caplog.text and "decoding the frame again" in caplog.text
    assert entry.stat().st_size > 1000, "the frame was not stored again whole"
    # an entry holding arrays of another kind (a foreign file under the cache's name)
    np.save(entry, np.zeros((H, W), np.float64))
    _assert_same(_frames(folder), want)


def test_a_full_cache_stores_nothing_more_and_frames_are_still_read(
        tmp_path: Path, cache_dir: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven")
    one_frame = H * W * 3 + H * W * 4 + 1000
    monkeypatch.setenv(BOUND_ENV, str(1.5 * one_frame / 1e9))
    with caplog.at_level(logging.INFO):
        frames = _frames(folder)
    assert len(frames) == 3 and len(list(cache_dir.glob(f"*{SUFFIX}"))) == 1
    assert "at its" in caplog.text and "bound" in caplog.text
    monkeypatch.setenv(BOUND_ENV, "0")
    _assert_same(_frames(folder), frames)


def test_a_cache_that_cannot_be_written_costs_a_decode(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven", frames=2)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv(CACHE_ENV, str(blocker / "cache"))
    with caplog.at_level(logging.WARNING):
        frames = _frames(folder)
    assert len(frames) == 2 and caplog.text.count("not written") == 1      # said once


def test_a_corrupt_image_is_skipped_every_pass_and_never_cached(
        tmp_path: Path, cache_dir: Path) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven")
    (folder / "frame-000001.depth.png").write_bytes(b"not a png")
    for _ in range(2):
        sequence = _opened(folder)
        assert [f.index for f in sequence] == [0, 2]
        assert sequence.skipped == [str(folder / "frame-000001.depth.png")]
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 2


def test_a_killed_writers_leftover_is_removed_and_a_live_ones_kept(
        tmp_path: Path, cache_dir: Path) -> None:
    """A process killed between writing an entry and renaming it leaves a frame's worth of
    temporary file that nothing reads: the next process to store removes it once it is old,
    never one a writer may still be renaming."""
    cache_dir.mkdir(parents=True)
    stale, fresh = cache_dir / f"tmpold{PARTIAL}", cache_dir / f"tmpnew{PARTIAL}"
    for leftover in (stale, fresh):
        leftover.write_bytes(b"\0" * 1024)
    old = time.time() - STALE_PARTIAL_S - 60
    os.utime(stale, (old, old))
    _frames(_seven_scenes_folder(tmp_path / "seven", frames=1))
    assert not stale.exists() and fresh.exists()
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 1


@pytest.mark.parametrize("bound", ["lots", "-1", "nan"])
def test_a_bound_that_is_not_a_size_is_refused(tmp_path: Path, cache_dir: Path,
                                               monkeypatch: pytest.MonkeyPatch,
                                               bound: str) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven", frames=1)
    monkeypatch.setenv(BOUND_ENV, bound)
    with pytest.raises(SequenceError, match=f"{BOUND_ENV}=.*a size in GB expected"):
        _opened(folder)


def test_a_synthetic_world_played_again_is_read_back_not_rendered(
        cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames of one walk are one entry each, whatever the sequence's length or first frame
    (the renderer's input is the world, the camera and its pose); another walk or world is
    rendered, never answered with the first one's pixels."""
    rendered = list(open_sequence("synthetic:4", 2, 4))              # no cache: the truth
    first = list(open_sequence("synthetic:4", 2, 4, frame_cache=DecodedFrameCache(
        cache_dir, 10**9)))
    _assert_same(first, rendered)
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 2

    def refuse(*args: object) -> None:
        raise AssertionError("rendered although the frame was in the cache")
    monkeypatch.setattr(synthetic, "_cast", refuse)
    longer = open_sequence("synthetic:30", 2, 4, frame_cache=DecodedFrameCache(cache_dir, 10**9))
    _assert_same(list(longer), rendered)
    monkeypatch.undo()
    for other in ("synthetic:4:1", "synthetic-corridor:4"):
        frames = list(open_sequence(other, 2, 4, frame_cache=DecodedFrameCache(cache_dir, 10**9)))
        assert not np.array_equal(frames[0].color, rendered[0].color), other
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 6
