"""Depth registered to a colour camera that is not the depth camera (7-Scenes' raw Kinect
frames): where a reading lands, which one wins, and a folder read through another colour
camera."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.data_paths import SEVEN, needs_seven
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.sequences.registration import register_depth

H, W = 48, 64
DEPTH_K = np.array([[58.5, 0, 32.0], [0, 58.5, 24.0], [0, 0, 1]])
COLOUR_K = np.array([[52.5, 0, 32.0], [0, 52.5, 24.0], [0, 0, 1]])


def _reading_at(u: int, v: int, z: float) -> np.ndarray:
    depth = np.zeros((H, W), dtype=np.float32)
    depth[v, u] = z
    return depth


def test_a_reading_lands_where_the_colour_camera_sees_its_point() -> None:
    """A point 20 px right of the depth camera's centre is 20·525/585 ≈ 18 px right of the
    colour camera's: its depth moves there, unchanged, and nowhere else."""
    out = register_depth(_reading_at(52, 24, 2.0), DEPTH_K, COLOUR_K)
    assert out.dtype == np.float32 and out.shape == (H, W)
    expected_u = round(32 + 20 * 52.5 / 58.5)
    assert out[24, expected_u] == pytest.approx(2.0)
    assert np.count_nonzero(out) == 1


def test_depth_in_millimetres_comes_back_in_its_own_type() -> None:
    """A 16-bit depth image (millimetres, as TUM and 7-Scenes store it) is registered as
    metres are and returned as 16-bit."""
    depth = np.zeros((H, W), dtype=np.uint16)
    depth[24, 52] = 2000
    out = register_depth(depth, DEPTH_K, COLOUR_K)
    assert out.dtype == np.uint16 and out[24, round(32 + 20 * 52.5 / 58.5)] == 2000
    assert np.count_nonzero(out) == 1


def test_the_nearer_of_two_readings_on_one_colour_pixel_is_kept() -> None:
    """Two depth pixels that land on one colour pixel: the surface in front hides the other."""
    depth = np.zeros((H, W), dtype=np.float32)
    depth[24, 36] = 3.0
    depth[24, 37] = 1.5           # 4 px · 0.897 and 5 px · 0.897 round to the same column
    out = register_depth(depth, DEPTH_K, COLOUR_K)
    assert np.count_nonzero(out) == 1 and out[out > 0][0] == pytest.approx(1.5)


def test_the_baseline_between_the_cameras_moves_the_reading_and_its_depth() -> None:
    """The colour camera 0.1 m to the left of the depth camera (a point at x = 0 in the depth
    frame is at x = 0.1 in the colour frame) and 0.05 m behind it."""
    depth_to_colour = np.eye(4)
    depth_to_colour[:3, 3] = [0.1, 0.0, 0.05]
    out = register_depth(_reading_at(32, 24, 2.0), DEPTH_K, COLOUR_K, depth_to_colour)
    v, u = np.argwhere(out > 0)[0]
    assert (v, u) == (24, round(32 + 52.5 * 0.1 / 2.05))
    assert out[v, u] == pytest.approx(2.05)


def test_cameras_at_one_place_register_as_a_zero_baseline_does() -> None:
    """Without a baseline each column and row of the depth image lands on one column and row of
    the colour image (the shortcut the player takes on 7-Scenes): a noisy scene with holes
    comes out as the full per-pixel warp with the identity transform makes it."""
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.5, 4.0, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.2] = 0.0
    for colour_k in (COLOUR_K, np.array([[64.0, 0, 30.0], [0, 64.0, 26.0], [0, 0, 1]])):
        shortcut = register_depth(depth, DEPTH_K, colour_k)
        full = register_depth(depth, DEPTH_K, colour_k, np.eye(4))
        assert np.count_nonzero(shortcut) > 0.5 * depth.size
        np.testing.assert_array_equal(shortcut, full)


def test_nonsense_cameras_are_refused() -> None:
    with pytest.raises(ValueError, match="colour camera's intrinsics"):
        register_depth(np.ones((H, W)), DEPTH_K, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="H×W"):
        register_depth(np.ones((H, W, 1)), DEPTH_K, COLOUR_K)
    with pytest.raises(ValueError, match="4×4"):
        register_depth(np.ones((H, W)), DEPTH_K, COLOUR_K, np.eye(3))


def _seven_scenes_folder(root: Path) -> Path:
    """A two-frame 7-Scenes folder: a wall 2 m away seen by the depth camera in full."""
    root.mkdir()
    np.savetxt(root / "camera-intrinsics.txt", DEPTH_K)
    for i in range(2):
        colour = np.random.default_rng(i).integers(0, 255, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(root / f"frame-{i:06d}.color.png"), colour)
        cv2.imwrite(str(root / f"frame-{i:06d}.depth.png"), np.full((H, W), 2000, np.uint16))
        np.savetxt(root / f"frame-{i:06d}.pose.txt", np.eye(4))
    return root


def test_a_folder_read_through_its_colour_camera_carries_its_intrinsics_and_registered_depth(
        tmp_path: Path) -> None:
    """The depth camera's 585-like focal in the folder, a 525-like colour camera given as a
    file (the player's ``colour_intrinsics``): frames carry the colour camera's intrinsics;
    the wider colour view leaves a border the depth camera never saw without depth, and every
    depth reading is still the wall's."""
    folder = _seven_scenes_folder(tmp_path / "seven")
    colour_file = tmp_path / "colour.txt"
    np.savetxt(colour_file, COLOUR_K)
    raw = open_sequence(folder)
    seen = open_sequence(folder, 0, -1, str(colour_file))
    assert np.array_equal(raw.intrinsics, DEPTH_K) and np.array_equal(seen.intrinsics, COLOUR_K)
    frames = list(seen)
    assert len(frames) == 2 and np.array_equal(frames[0].intrinsics, COLOUR_K)
    depth = frames[0].depth
    assert depth is not None and np.all(depth[depth > 0] == pytest.approx(2.0))
    assert np.all(depth[:, 0] == 0) and np.all(depth[24, 6:58] > 0)
    assert np.all(next(iter(raw)).depth > 0)                    # the raw image: depth everywhere
    assert np.array_equal(seen.select(1).intrinsics, COLOUR_K)  # a selection stays registered
    assert open_sequence(folder, 0, -1, "").intrinsics[0, 0] == DEPTH_K[0, 0]


def test_auto_sees_a_seven_scenes_scene_through_its_colour_camera_and_nothing_else(
        tmp_path: Path) -> None:
    """The player's default: a 7-Scenes scene (its file holds the dataset's depth camera, 585
    px) through the colour camera the bundled file writes; a 7-Scenes-like folder with a
    camera of its own and a synthetic world as they are."""
    scene = _seven_scenes_folder(tmp_path / "scene")
    np.savetxt(scene / "camera-intrinsics.txt", [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    colour = np.loadtxt(Path(__file__).resolve().parents[1] / "config"
                        / "7scenes-colour-intrinsics.txt")
    seen = open_sequence(scene, 0, -1, "auto")
    assert np.array_equal(seen.intrinsics, colour)
    assert np.array_equal(next(iter(seen)).intrinsics, colour)
    own = _seven_scenes_folder(tmp_path / "own-camera")
    assert np.array_equal(open_sequence(own, 0, -1, "auto").intrinsics, DEPTH_K)
    synthetic = open_sequence("synthetic:5", 0, -1, "auto")
    assert np.array_equal(synthetic.intrinsics, open_sequence("synthetic:5").intrinsics)


def test_colour_intrinsics_that_cannot_apply_are_clear_errors(tmp_path: Path) -> None:
    folder = _seven_scenes_folder(tmp_path / "seven")
    with pytest.raises(SequenceError, match="missing file"):
        open_sequence(folder, 0, -1, str(tmp_path / "no-such-file.txt"))
    bad = tmp_path / "bad.txt"
    np.savetxt(bad, np.eye(2))
    with pytest.raises(SequenceError, match="3×3"):
        open_sequence(folder, 0, -1, str(bad))
    with pytest.raises(SequenceError, match="registered already"):
        open_sequence("synthetic:10", 0, -1, COLOUR_K)
    with pytest.raises(SequenceError, match="needs the colour camera"):
        open_sequence(folder, 0, -1, None, np.eye(4))


def test_a_colour_camera_placed_off_the_depth_camera_moves_the_folder_s_readings(
        tmp_path: Path) -> None:
    """``open_sequence``'s depth-to-colour transform reaches the registration: the colour
    camera 10 cm right of the depth camera sees the wall's readings shifted left."""
    folder = _seven_scenes_folder(tmp_path / "seven")
    beside = np.eye(4)
    beside[0, 3] = -0.10                       # a depth-frame point is 10 cm left of the colour
    same = next(iter(open_sequence(folder, 0, -1, COLOUR_K))).depth
    moved = next(iter(open_sequence(folder, 0, -1, COLOUR_K, beside))).depth
    assert same is not None and moved is not None
    shift = 52.5 * 0.10 / 2.0                   # f·b/z pixels at the wall's 2 m
    assert int(np.flatnonzero(moved[24] > 0).max()) == pytest.approx(
        int(np.flatnonzero(same[24] > 0).max()) - shift, abs=1)


@needs_seven
def test_the_seven_scenes_sample_registered_to_its_colour_camera_keeps_its_depths() -> None:
    """The bundled sample through config/7scenes-colour-intrinsics.txt: the same readings,
    moved (the median depth of a frame barely changes; fewer pixels are covered)."""
    colour = Path(__file__).resolve().parents[1] / "config" / "7scenes-colour-intrinsics.txt"
    raw = next(iter(open_sequence(SEVEN, 0, 1)))
    seen = next(iter(open_sequence(SEVEN, 0, 1, str(colour))))
    assert seen.intrinsics[0, 0] == 525.0 and raw.intrinsics[0, 0] == 585.0
    assert raw.depth is not None and seen.depth is not None
    before, after = raw.depth[raw.depth > 0], seen.depth[seen.depth > 0]
    assert abs(np.median(after) - np.median(before)) < 0.05
    assert 0.6 < after.size / before.size < 0.95
