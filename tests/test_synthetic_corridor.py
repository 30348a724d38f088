"""The synthetic corridor: the world a clone without a dataset plays where the edge's map
matters — exact depth to the sensor's range, a walk out and back, walls that never repeat."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from twinslam.live.runs import sequence_for
from twinslam.sequences.frame import RgbdFrame, SequenceError
from twinslam.sequences.opening import is_synthetic, open_sequence
from twinslam.sequences.synthetic import SyntheticSequence
from twinslam.sequences.synthetic_worlds import (
    CORRIDOR_HALF,
    CORRIDOR_MAX_DEPTH_M,
    CORRIDOR_TEXEL_M,
    FPS,
    WALK_SPEED_M_S,
    corridor,
)


def _world_points(frame_depth: np.ndarray, k: np.ndarray, pose: np.ndarray) -> np.ndarray:
    h, w = frame_depth.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    z = frame_depth.astype(np.float64)
    cam = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], -1)
    cam = cam.reshape(-1, 3)[z.reshape(-1) > 0]
    return cam @ pose[:3, :3].T + pose[:3, 3]


def test_depth_is_exact_to_the_sensors_range_and_zero_beyond() -> None:
    seq = open_sequence("synthetic-corridor:240:1")
    assert seq.kind == "synthetic" and len(seq) == 240
    looked_far = False
    for frame in list(seq)[::40]:
        assert frame.depth is not None and frame.pose is not None
        world = _world_points(frame.depth, frame.intrinsics, frame.pose)
        on_face = np.max(np.abs(world) / CORRIDOR_HALF, axis=1)
        np.testing.assert_allclose(on_face, 1.0, atol=1e-5)
        assert frame.depth.max() <= CORRIDOR_MAX_DEPTH_M
        looked_far |= bool((frame.depth == 0).any())
    assert looked_far, "somewhere the camera looks down the corridor past the sensor's range"


def test_the_walk_goes_out_turns_round_and_comes_back_without_a_jump() -> None:
    span_s = 2 * (CORRIDOR_HALF[2] - 1.5) / WALK_SPEED_M_S
    seq = SyntheticSequence(int((span_s + 10) * FPS), seed=3, world_name="corridor")
    poses = np.array(seq.poses)
    z = poses[:, 2, 3]
    assert z[0] < -CORRIDOR_HALF[2] + 2 and z.max() > CORRIDOR_HALF[2] - 2
    assert z[-1] < z.max() - 1.0, "after the far end it walks back"
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 1.5 * WALK_SPEED_M_S / FPS + 0.01
    # the view direction (camera z) points forward on the way out, back on the way back
    assert poses[: int(5 * FPS), 2, 2].mean() > 0.3 and poses[-int(5 * FPS):, 2, 2].mean() < -0.3
    assert (np.abs(poses[:, :3, 3]) < CORRIDOR_HALF).all()


def _surface_cells(frame: RgbdFrame, cell_m: float = 0.1) -> set[tuple[int, int, int]]:
    """The 10 cm cells of surface a frame sees with depth (every 8th pixel)."""
    assert frame.depth is not None and frame.pose is not None
    k = frame.intrinsics.copy()
    k[:2] /= 8
    points = _world_points(frame.depth[::8, ::8], k, frame.pose)
    return set(map(tuple, np.floor(points / cell_m).astype(int).tolist()))


def test_a_view_is_out_of_sight_a_few_metres_on() -> None:
    """Two views 5 m apart on the walk share (almost) no surface, so the keyframes of a place
    are what its revisit needs and only a map that kept them has them; 1 m apart they share
    much of it (a device walking on tracks from one slot to the next)."""
    seq = SyntheticSequence(600, seed=0, world_name="corridor")
    frames = [seq.read(i) for i in range(0, 600, 30)]
    cells = [_surface_cells(f) for f in frames]
    far, near = [], []
    for i, j in zip(*np.triu_indices(len(frames), 1), strict=True):
        a, b = frames[i].pose, frames[j].pose
        assert a is not None and b is not None
        apart = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
        shared = len(cells[i] & cells[j]) / min(len(cells[i]), len(cells[j]))
        (far if apart > 5.0 else near if apart < 1.0 else []).append(shared)
    assert len(far) > 30 and len(near) > 10
    assert np.mean(far) < 0.01 and max(far) < 0.1
    assert np.mean(near) > 0.2


def test_its_walls_never_repeat() -> None:
    """No metre of a side wall looks like another: under a tenth of its ORB features find a
    close match on any other metre of the wall, where a tiled texture matches itself."""
    wall = corridor().textures[0]
    metre = int(1.0 / CORRIDOR_TEXEL_M)
    orb = cv2.ORB_create(300)
    grey = cv2.cvtColor(wall, cv2.COLOR_RGB2GRAY)
    sections = [orb.detectAndCompute(np.ascontiguousarray(grey[:, i:i + metre]), None)[1]
                for i in range(0, grey.shape[1] - metre + 1, metre)]
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    assert len(sections) >= 20
    for i, a in enumerate(sections):
        for b in sections[i + 1:]:
            close = [m for m in matcher.match(a, b) if m.distance < 30]
            assert len(close) < 0.1 * len(a)
    # the check can fail: a wall that repeats its first metre matches it nearly everywhere
    tiled = np.concatenate([grey[:, :metre]] * 2, axis=1)
    _, again = orb.detectAndCompute(np.ascontiguousarray(tiled[:, metre:]), None)
    repeats = [m for m in matcher.match(sections[0], again) if m.distance < 30]
    assert len(repeats) >= 0.5 * len(sections[0])


def test_a_corridor_spec_keeps_its_world_and_a_misspelt_one_is_refused() -> None:
    assert is_synthetic("synthetic-corridor:300") and not is_synthetic("synthetic_data/seq")
    assert sequence_for("synthetic-corridor:300", 4) == "synthetic-corridor:300:4"
    assert sequence_for("synthetic:300", 4) == "synthetic:300:4"
    walked = open_sequence(sequence_for("synthetic-corridor:30", 4))
    assert next(iter(walked)).name == "synthetic-corridor-000000"
    with pytest.raises(SequenceError, match="synthetic-corridor"):
        open_sequence("synthetic-hall:30")
