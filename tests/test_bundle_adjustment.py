"""GTSAM local bundle adjustment: recovers a perturbed map, keeps the fixed keyframe, and
flags wrong associations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from twinslam.slam.back_end.bundle_adjustment import Observation, bundle_adjust

K = np.array([[525.0, 0, 320], [0, 525, 240], [0, 0, 1]])


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _scene(rng: np.random.Generator, wrong: float = 0.0,
           cameras: dict[int, np.ndarray] | None = None):
    """6 keyframes sliding along x looking down +z at 200 points 2-5 m away, each seen by the
    camera ``K`` but those ``cameras`` names."""
    poses = {}
    for i in range(6):
        p = np.eye(4)
        p[:3, :3] = _rot(np.array([0.0, 1.0, 0.0]), 0.03 * i)
        p[:3, 3] = [0.15 * i, 0.02 * i, 0.0]
        poses[i] = p
    points = {j: rng.uniform([-1.5, -1.0, 2.0], [2.5, 1.0, 5.0]) for j in range(200)}
    obs, bad = [], []
    for i, pose in poses.items():
        cw = np.linalg.inv(pose)
        for j, xyz in points.items():
            cam = cw[:3, :3] @ xyz + cw[:3, 3]
            uv = ((cameras or {}).get(i, K) @ cam)[:2] / cam[2]
            if not (0 <= uv[0] < 640 and 0 <= uv[1] < 480):
                continue
            uv = uv + rng.normal(0, 0.5, 2)
            is_wrong = rng.random() < wrong
            if is_wrong:
                uv = uv + rng.choice([-1, 1], 2) * rng.uniform(15, 40, 2)
            depth = cam[2] + rng.normal(0, 0.01) if j % 2 == 0 else math.nan
            ob = Observation(i, j, (float(uv[0]), float(uv[1])), depth)
            obs.append(ob)
            if is_wrong:
                bad.append(ob)
    return poses, points, obs, bad


def _perturb(rng, poses, points):
    noisy_poses = {}
    for i, p in poses.items():
        q = p.copy()
        if i:
            q[:3, :3] = _rot(rng.normal(size=3), 0.02) @ q[:3, :3]
            q[:3, 3] += rng.normal(0, 0.03, 3)
        noisy_poses[i] = q
    noisy_points = {j: x + rng.normal(0, 0.08, 3) for j, x in points.items()}
    return noisy_poses, noisy_points


def test_bundle_adjustment_recovers_the_map_and_flags_wrong_matches() -> None:
    rng = np.random.default_rng(0)
    poses, points, obs, bad = _scene(rng, wrong=0.05)
    start_poses, start_points = _perturb(rng, poses, points)
    # 8-12 cm off is a cold start (the edge warm-starts from the device's poses and runs 3)
    res = bundle_adjust(start_poses, start_points, obs, K, fixed={0}, max_iterations=10)
    seen: dict[int, int] = {}
    for ob in obs:
        seen[ob.point] = seen.get(ob.point, 0) + 1
    kept = [j for j, n in seen.items() if n >= 3]          # constrained from several views
    before = np.median([np.linalg.norm(start_points[j] - points[j]) for j in kept])
    after = np.median([np.linalg.norm(res.points[j] - points[j]) for j in kept])
    pose_err = max(np.linalg.norm(res.poses[i][:3, 3] - poses[i][:3, 3]) for i in poses)
    flagged = set(map(id, res.outliers)) & set(map(id, bad))
    print(f"\n{len(obs)} observations ({len(bad)} wrong): median error of the {len(kept)} "
          f"points seen 3+ times {before * 100:.1f} -> "
          f"{after * 100:.2f} cm, worst keyframe {pose_err * 100:.2f} cm, error "
          f"{res.initial_error:.0f} -> {res.final_error:.0f} in {res.iterations} iterations, "
          f"{res.milliseconds:.0f} ms; {len(flagged)}/{len(bad)} wrong matches flagged, "
          f"{len(res.outliers) - len(flagged)} good ones")
    assert after < 0.04 and after < before / 3     # ~2 cm: depth noise 1 cm, half the points
    assert pose_err < 0.02                          # monocular only, baselines <= 0.75 m
    np.testing.assert_allclose(res.poses[0], poses[0], atol=1e-12)     # the fixed keyframe
    assert len(flagged) >= 0.9 * len(bad)
    assert len(res.outliers) - len(flagged) <= 0.01 * len(obs)


def test_bundle_adjustment_needs_a_fixed_keyframe_and_known_ids() -> None:
    rng = np.random.default_rng(1)
    poses, points, obs, _ = _scene(rng)
    with pytest.raises(ValueError, match="gauge"):
        bundle_adjust(poses, points, obs, K, fixed=set())
    with pytest.raises(ValueError, match="point 999"):
        bundle_adjust(poses, points, [*obs, Observation(0, 999, (1.0, 1.0))], K, fixed={0})


def test_keyframes_of_another_devices_camera_are_adjusted_with_its_intrinsics() -> None:
    """Keyframes 3-5 taken by another device's camera (450 px, not 525): adjusted with their
    own intrinsics, the true map stays where it is and no observation is an outlier; read
    with this device's, their pixels mean other rays — the adjustment moves the map by
    centimetres and throws a fifth of their observations out."""
    rng = np.random.default_rng(4)
    other = np.array([[450.0, 0, 320], [0, 450, 240], [0, 0, 1]])
    cameras = {i: other for i in (3, 4, 5)}
    poses, points, obs, _ = _scene(rng, cameras=cameras)
    theirs = [ob for ob in obs if ob.keyframe in cameras]
    right = bundle_adjust(poses, points, obs, K, fixed={0, 1}, max_iterations=5,
                          cameras=cameras)
    wrong = bundle_adjust(poses, points, obs, K, fixed={0, 1}, max_iterations=5)

    def moved(res) -> float:
        return max(np.linalg.norm(res.poses[i][:3, 3] - poses[i][:3, 3]) for i in poses)

    assert moved(right) < 0.005 and not right.outliers
    assert moved(wrong) > 0.02
    assert sum(ob.keyframe in cameras for ob in wrong.outliers) > len(theirs) // 5
