"""Files the edge wrote whole and that were damaged afterwards (a disk fault, a copy cut
short): each reads back as its own clear error, never as a traceback that stops the edge."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from edge_mapper.place_membership import PlaceMembership, run_after
from twinslam.npz_files import write_npz
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap, MapError


def _cut_short(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _bit_flipped(path: Path) -> None:
    """One bit of an array's bytes flipped: the zip's CRC of that member no longer holds."""
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0x10
    path.write_bytes(bytes(data))


DAMAGE = [pytest.param(_cut_short, id="cut-short"), pytest.param(_bit_flipped, id="bit-flip")]


def _keyframe(kf_id: int) -> ArchivedKeyFrame:
    rng = np.random.default_rng(kf_id)
    n = 400
    return ArchivedKeyFrame(kf_id, np.eye(4), np.arange(n, dtype=np.int64),
                            rng.normal(size=(n, 3)), rng.integers(0, 256, (n, 32), np.uint8),
                            rng.normal(size=(n, 3)), 1)


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_map_checkpoint_is_a_map_error(
        tmp_path: Path, damage: Callable[[Path], None]) -> None:
    m = KeyFrameMap()
    m.add_keyframe(0, np.eye(4))
    rng = np.random.default_rng(0)
    m.add_points(rng.normal(size=(400, 3)), rng.integers(0, 256, (400, 32), np.uint8))
    path = tmp_path / "edge.npz"
    m.save(path)
    assert len(KeyFrameMap.load(path)[0].points) == 400
    damage(path)
    with pytest.raises(MapError, match="not a readable map checkpoint"):
        KeyFrameMap.load(path)


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_archived_keyframe_is_named_and_the_rest_read(
        tmp_path: Path, damage: Callable[[Path], None]) -> None:
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(5, folder)
    for k in (1, 2):
        archive.add(_keyframe(k))
    damage(folder / "keyframe-000000002.npz")
    again, problems = KeyFrameArchive.restore(5, folder)
    assert [kf.id for kf in again] == [1]
    assert len(problems) == 1 and "keyframe-000000002.npz" in problems[0]
    assert "not a readable archived keyframe" in problems[0]


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_pose_file_is_named_and_the_keyframes_read(
        tmp_path: Path, damage: Callable[[Path], None]) -> None:
    folder = tmp_path / "edge.npz.archive"
    archive = KeyFrameArchive(50, folder)
    for k in range(1, 40):          # a pose file large enough that a flipped bit is in a pose
        archive.add(_keyframe(k))
    shift = np.eye(4)
    shift[2, 3] = 0.1
    archive.correct(dict.fromkeys(range(1, 40), shift))
    damage(folder / "poses.npz")
    again, problems = KeyFrameArchive.restore(50, folder)
    assert len(again) == 39
    assert len(problems) == 1 and "poses.npz" in problems[0]
    np.testing.assert_array_equal(again.get(7).pose, np.eye(4))


def test_a_map_set_aside_whose_file_was_cut_short_counts_as_the_first(tmp_path: Path) -> None:
    aside = tmp_path / "edge.ar1.npz.reclaimed"
    write_npz(aside, PlaceMembership("ar2", {}, run=2).arrays())
    assert run_after(aside) == 3
    _cut_short(aside)
    assert run_after(aside) == 1
