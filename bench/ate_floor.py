"""How low the ATE of a walk can go with its camera model and its ground truth: the edge's map
of the whole walk optimised as a whole, loops closed, and the ground truth's own fit to the
images beside it.

    python -m bench.ate_floor [SEQUENCE] [--frames 1000] [--colour-intrinsics FILE]
        [--loop-gap 60] [--baseline-m 0.08] [--csv FILE]

The paper's device tracks the walk played forward once against the edge's map (the settings
of the live paper's device, ``docs/figures/colour-camera/short-loop-own-map.yaml``: slots of
30 frames, D_req 0.25 s, LFF, the device's own points after 0.1 s lost; the uplink at 60
Mbit/s, every upload arriving), with no V_max: every keyframe the edge asks for stays. Then
each stage is printed with the keyframes' ATE, the median reprojection error of every
observation and the share within 3 px:

1. **online** — the map as the edge built it, slot by slot (local bundle adjustment of the
   newest five keyframes);
2. **full BA** — one bundle adjustment of every keyframe and point (GTSAM, the edge's own
   factors, the first keyframe held): the best the map's associations allow;
3. **full BA, loops fused** — each keyframe's points matched by projection against the points
   of keyframes at least ``--loop-gap`` frames apart (ORB-SLAM's loop fusion: a strict
   descriptor match within 8 px of the projection, the depths agreeing within 5 %), the
   duplicates merged, and the full adjustment again: what closing every loop of the walk could
   reach, offline and with the whole future known — a floor no online device goes under;
4. **ground truth, points free** — every keyframe held at its ground-truth pose (moved into
   the map's frame by the ATE's alignment), only the points adjusted: how well the truth
   itself explains the images, beside the optimum's fit.

Where stage 3's ATE is above a goal, no loop closing or map policy reaches the goal on this
walk; where stage 4 fits the images worse than stage 3, the rest of the distance is the ground
truth's (or the camera model's), not the tracker's.
"""

from __future__ import annotations

import argparse
import csv
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.front_end_drift import SEQUENCE
from bench.in_process import serve_slot
from device_tracker.device_core import DeviceTrackerCore
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.slot_planner import SlotConfig
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import absolute_trajectory_error, truth_in_map
from twinslam.policies.registry import make_policy
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.bundle_adjustment import Observation, bundle_adjust, reprojection_sq
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.front_end.tracking import TrackingConfig
from twinslam.slam.projection_matching import match_by_projection, visible_points

#: pixels: a reprojection error within this is an inlier (the trackers' threshold)
INLIER_PX = 3.0
#: loop fusion's match: this near the projection, this few bits apart, this clear of the
#: runner-up, and a measured depth within this share of the projected one
FUSE_RADIUS_PX = 8.0
FUSE_MAX_HAMMING = 40
FUSE_RATIO = 0.7
FUSE_DEPTH_SHARE = 0.05


@dataclass(frozen=True)
class Stage:
    """One row: a set of keyframe poses and point positions, and how it fits."""

    name: str
    keyframes: int
    points: int
    observations: int
    ate_m: float                 #: keyframes against the truth (NaN: the truth itself)
    median_px: float             #: reprojection error of the observations
    within_px: float             #: share of the observations within INLIER_PX


@dataclass
class WalkMap:
    """The edge's map of the walk and the ground truth of its keyframes."""

    map: KeyFrameMap
    intrinsics: np.ndarray
    truth: dict[int, np.ndarray]           #: keyframe id → camera-to-world ground truth
    image_shape: tuple[int, int]


def build_map(sequence: str, frames: int, colour_intrinsics: str | None) -> WalkMap:
    """The paper's device and an edge without V_max over ``frames`` of ``sequence`` played
    forward once (the depth registered to the colour camera of the ``colour_intrinsics`` file
    when given)."""
    reader = open_sequence(sequence, 0, frames, colour_intrinsics=colour_intrinsics)
    k = reader.intrinsics
    tracking = TrackingConfig(relocalise=True, reloc_min_inliers=20, reloc_probation_frames=5)
    device = DeviceTrackerCore(k, 30, tracking, keep_slots=4, frame_rate_hz=30.0,
                               map_source="edge", own_map_after=3)
    truth: dict[int, np.ndarray] = {}
    shape = (480, 640)
    with tempfile.TemporaryDirectory() as tmp:
        config = EdgeConfig(slot=SlotConfig(vmax=100_000, d_req_s=0.25))
        edge = EdgeMapperCore(make_policy("lff"), k, config, Path(tmp) / "edge.npz")
        for n, frame in enumerate(reader):
            result = device.track(frame.color, frame.depth, n / 30.0)
            if frame.pose is not None:
                truth[result.record.frame_id] = frame.pose
            shape = (int(frame.color.shape[0]), int(frame.color.shape[1]))
            if result.slot_done:
                serve_slot(device, edge, 60.0, 1)
            if n % 200 == 0:
                print(f"  frame {n}/{len(reader)}: {len(edge.map.keyframes)} keyframes",
                      flush=True)
        return WalkMap(edge.map, edge.k, truth, shape)


def observations(m: KeyFrameMap) -> list[Observation]:
    """Every measured observation of the map (where a keyframe saw a point, and its depth)."""
    out = []
    for kf_id in m.keyframe_ids():
        kf = m.keyframes[kf_id]
        for pid in kf.points:
            u, v, d = kf.measurements.get(pid, (math.nan, math.nan, math.nan))
            if math.isfinite(u) and math.isfinite(v):
                out.append(Observation(kf_id, pid, (u, v), d))
    return out


def fuse_loops(m: KeyFrameMap, poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
               obs: list[Observation], k: np.ndarray, shape: tuple[int, int], gap: int
               ) -> tuple[list[Observation], int]:
    """``obs`` with the points that keyframes ``gap`` or more frames apart both saw merged into
    one (the older's): each keyframe's measured points are matched by projection, at
    ``poses``/``points``, against the points of the far keyframes it does not observe.
    Returns the merged observations (one per keyframe and point) and how many points merged."""
    parent: dict[int, int] = {}

    def root(p: int) -> int:
        while parent.get(p, p) != p:
            p = parent[p]
        return p

    merged = 0
    ids = sorted(poses)
    for j in ids:
        kf = m.keyframes[j]
        own = [p for p in sorted(kf.points) if p in points
               and math.isfinite(kf.measurements.get(p, (math.nan,))[0])]
        far = sorted({p for i in ids if abs(i - j) >= gap for p in m.keyframes[i].points}
                     - kf.points)
        far = [p for p in far if p in points]
        if not own or not far:
            continue
        world = np.array([points[p] for p in far])
        rows, uv = visible_points(world, np.ones(len(far), dtype=bool), poses[j], k, shape,
                                  (0.1, math.inf))
        if rows.size == 0:
            continue
        depth_row = np.linalg.inv(poses[j])[2]          # a point's depth in keyframe j
        feature_xy = np.array([kf.measurements[p][:2] for p in own])
        feature_desc = np.array([m.points[p].descriptor for p in own], dtype=np.uint8)
        far_desc = np.array([m.points[far[r]].descriptor for r in rows], dtype=np.uint8)
        f_idx, c_idx = match_by_projection(feature_xy, feature_desc, uv, far_desc,
                                           FUSE_RADIUS_PX, FUSE_MAX_HAMMING, FUSE_RATIO, shape)
        for f, c in zip(f_idx.tolist(), c_idx.tolist(), strict=True):
            depth = kf.measurements[own[f]][2]
            projected = float(depth_row[:3] @ world[rows[c]] + depth_row[3])
            if math.isfinite(depth) and abs(depth - projected) > FUSE_DEPTH_SHARE * depth:
                continue
            a, b = root(own[f]), root(far[rows[c]])
            if a != b:
                parent[max(a, b)] = min(a, b)
                merged += 1
    out: dict[tuple[int, int], Observation] = {}
    for ob in obs:
        key = (ob.keyframe, root(ob.point))
        out.setdefault(key, Observation(ob.keyframe, key[1], ob.uv, ob.depth))
    return list(out.values()), merged


def stage(name: str, poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
          obs: list[Observation], k: np.ndarray, truth: dict[int, np.ndarray] | None
          ) -> Stage:
    """The row of a set of poses and points: ATE against ``truth`` (None: they are it)."""
    used = [ob for ob in obs if ob.point in points]
    errors = np.sqrt(reprojection_sq(poses, points, k, used))
    ate = absolute_trajectory_error(poses, truth) if truth is not None else math.nan
    return Stage(name, len(poses), len({ob.point for ob in used}), len(used), ate,
                 float(np.median(errors)), float(np.mean(errors <= INLIER_PX)))


def floors(walk: WalkMap, gap: int, baseline_m: float) -> list[Stage]:
    """The four stages of the module's docstring, the offline adjustments weighing depth with
    a virtual stereo ``baseline_m``."""
    m, k = walk.map, walk.intrinsics
    ids = m.keyframe_ids()
    truth = {i: walk.truth[i] for i in ids if i in walk.truth}
    obs = observations(m)
    online_poses = {i: m.keyframes[i].pose for i in ids}
    online_points = {p: pt.position for p, pt in m.points.items()}
    rows = [stage("online (local BA of the newest 5)", online_poses, online_points, obs, k,
                  truth)]
    print("  full bundle adjustment ...", flush=True)
    full = bundle_adjust(online_poses, online_points, obs, k, {ids[0]}, baseline_m=baseline_m,
                         max_iterations=10)
    rows.append(stage("full BA", full.poses, full.points, obs, k, truth))
    print("  loop fusion ...", flush=True)
    fused_obs, merged = fuse_loops(m, full.poses, full.points, obs, k, walk.image_shape, gap)
    fused_points = {p: full.points[p] for p in {ob.point for ob in fused_obs}}
    fused = bundle_adjust(full.poses, fused_points, fused_obs, k, {ids[0]},
                          baseline_m=baseline_m, max_iterations=10)
    rows.append(stage(f"full BA, loops fused ({merged} points merged)", fused.poses,
                      fused.points, fused_obs, k, truth))
    print("  the ground truth's fit ...", flush=True)
    held = {i: p for i, p in truth_in_map(fused.poses, truth).items() if i in fused.poses}
    seen_by_held = [ob for ob in fused_obs if ob.keyframe in held]
    on_truth = bundle_adjust(held, fused.points, seen_by_held, k, set(held),
                             baseline_m=baseline_m, max_iterations=10)
    rows.append(stage("ground truth, points free", on_truth.poses, on_truth.points,
                      seen_by_held, k, None))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEQUENCE),
                        help="an RGB-D folder with ground truth (7-Scenes, TUM, SUN3D)")
    parser.add_argument("--frames", type=int, default=1000,
                        help="frames of the sequence played forward once")
    parser.add_argument("--colour-intrinsics", default=None, metavar="FILE",
                        help="the colour camera's 3×3 intrinsics file, the depth registered "
                        "to it (config/7scenes-colour-intrinsics.txt for 7-Scenes)")
    parser.add_argument("--loop-gap", type=int, default=60,
                        help="frames apart two keyframes must be for loop fusion to merge "
                        "their points (nearer ones the edge's local mapping associates "
                        "already)")
    parser.add_argument("--baseline-m", type=float, default=BackEndConfig().baseline_m,
                        metavar="B", help="the virtual stereo baseline the offline adjustments "
                        "weigh a depth reading with (the edge's; larger: depth counts more, "
                        "one pixel of disparity being a smaller depth error)")
    parser.add_argument("--csv", type=Path, default=None, metavar="FILE",
                        help="write the stages here too")
    args = parser.parse_args()
    if args.frames < 60:
        parser.error(f"--frames must be at least 60 (two slots), got {args.frames}")
    if not args.baseline_m > 0:
        parser.error(f"--baseline-m must be a positive number of metres, got {args.baseline_m}")
    if args.loop_gap < 1:
        parser.error(f"--loop-gap must be at least 1 frame, got {args.loop_gap}")
    cv2.setNumThreads(1)
    try:
        walk = build_map(args.sequence, args.frames, args.colour_intrinsics)
    except SequenceError as exc:
        parser.error(str(exc))
    if len(walk.truth) < 3:
        parser.error(f"{args.sequence}: fewer than 3 keyframes have ground truth")
    rows = floors(walk, args.loop_gap, args.baseline_m)
    camera = (f"the depth registered to {args.colour_intrinsics}" if args.colour_intrinsics
              else "the folder's own intrinsics")
    print(f"\n{args.frames} frames forward, {len(walk.map.keyframes)} keyframes, {camera}")
    print("| stage | keyframes | points | observations | keyframe ATE (m) | median "
          f"reprojection (px) | within {INLIER_PX:g} px |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ate = "—" if math.isnan(r.ate_m) else f"{r.ate_m:.4f}"
        print(f"| {r.name} | {r.keyframes} | {r.points} | {r.observations} | {ate} | "
              f"{r.median_px:.2f} | {100 * r.within_px:.1f} % |")
    if args.csv is not None:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            out = csv.writer(fh)
            out.writerow(["stage", "keyframes", "points", "observations", "keyframe_ate_m",
                          "median_reprojection_px", "within_3px"])
            for r in rows:
                out.writerow([r.name, r.keyframes, r.points, r.observations,
                              "" if math.isnan(r.ate_m) else f"{r.ate_m:.5f}",
                              f"{r.median_px:.4f}", f"{r.within_px:.4f}"])
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
