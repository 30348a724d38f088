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

Beside the ATE, each stage's keyframes are scored as anchored content is: the **revisit
error** (pairs of keyframes at least 10 s apart whose true poses lie within 0.3 m and 20°,
the error of their relative pose against the truth's: what one device's own anchor moves on
its return) and the **nearby error** (every pair of distinct keyframes within 0.3 m and 20°,
however far apart in time: what two devices that both held these poses would score on the
cross-device revisit error, the pairs of one frame with itself left out), and the latter's
pairs taken under 1 s apart alone (**close**: what the truth says of a step the camera took
just now); last, the nearby pairs' three bands (under 1 s, 1-10 s, 10 s and more apart)
weighed by their shares among the pairs of every frame played (**at the frames' mix**: the
live figures pair every tracked frame, more of them close in time). Stage 3's figures are
what a map consistent with every loop of the walk reaches against this ground truth.

Where stage 3's ATE is above a goal, no loop closing or map policy reaches the goal on this
walk; where stage 4 fits the images worse than stage 3, the rest of the distance is the ground
truth's (or the camera model's), not the tracker's.
"""

from __future__ import annotations

import argparse
import csv
import math
import tempfile
from collections.abc import Mapping, Sequence
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
from twinslam.live.tracking_quality import (
    REVISIT_ANGLE_DEG,
    REVISIT_GAP_S,
    REVISIT_RADIUS_M,
    absolute_trajectory_error,
    revisit_error,
    truth_in_map,
)
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
#: seconds: nearby keyframes this close in time are one step of the walk (the close column)
CLOSE_S = 1.0


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
    revisit_m: float = math.nan  #: RMS revisit error of the keyframes (NaN: the truth itself)
    nearby_m: float = math.nan   #: RMS error of every nearby pair, no time gap
    close_m: float = math.nan    #: ... of the nearby pairs under CLOSE_S apart
    frames_m: float = math.nan   #: ... of the nearby pairs weighed as every frame's pairs are


@dataclass
class WalkMap:
    """The edge's map of the walk and the ground truth of its keyframes."""

    map: KeyFrameMap
    intrinsics: np.ndarray
    truth: dict[int, np.ndarray]           #: keyframe id → camera-to-world ground truth
    image_shape: tuple[int, int]
    stamps_ns: dict[int, int]              #: frame id → its capture time on the walk's clock


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
    stamps: dict[int, int] = {}
    shape = (480, 640)
    with tempfile.TemporaryDirectory() as tmp:
        config = EdgeConfig(slot=SlotConfig(vmax=100_000, d_req_s=0.25))
        edge = EdgeMapperCore(make_policy("lff"), k, config, Path(tmp) / "edge.npz")
        for n, frame in enumerate(reader):
            result = device.track(frame.color, frame.depth, n / 30.0)
            stamps[result.record.frame_id] = round(n * 1e9 / 30.0)
            if frame.pose is not None:
                truth[result.record.frame_id] = frame.pose
            shape = (int(frame.color.shape[0]), int(frame.color.shape[1]))
            if result.slot_done:
                serve_slot(device, edge, 60.0, 1)
            if n % 200 == 0:
                print(f"  frame {n}/{len(reader)}: {len(edge.map.keyframes)} keyframes",
                      flush=True)
        return WalkMap(edge.map, edge.k, truth, shape, stamps)


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


#: the nearby pairs' bands by time apart (s): one step of the walk, the walk between, a
#: revisit (REVISIT_GAP_S on: the revisit error's pairs)
BANDS = ((0.0, CLOSE_S), (CLOSE_S, REVISIT_GAP_S), (REVISIT_GAP_S, math.inf))


def band_sums(poses: Mapping[int, np.ndarray], truth: Mapping[int, np.ndarray]
              ) -> list[tuple[int, float]]:
    """Per band of BANDS, the nearby pairs of ``poses`` (capture ns → camera-to-map, with
    ``truth`` in the same keys) and the sum of their squared errors: the pairs at least a
    band's lower bound apart less those at least its upper bound apart."""
    def at_least(gap_s: float) -> tuple[int, float]:
        if math.isinf(gap_s):
            return 0, 0.0
        # a gap of 0: every pair of two distinct frames (revisit_error's keys are unique)
        e = revisit_error(poses, truth, poses, gap_s=gap_s)
        return e.pairs, (e.rms_m ** 2 * e.pairs if e.pairs else 0.0)

    out = []
    for low, high in BANDS:
        (n_low, sq_low), (n_high, sq_high) = at_least(low), at_least(high)
        out.append((n_low - n_high, max(sq_low - sq_high, 0.0)))
    return out


def frames_mix(truth_ns: Mapping[int, np.ndarray]) -> list[float]:
    """The share of each band among the nearby pairs of every frame played (by the truth
    alone): the live figures pair every tracked frame, more of them close in time than a
    keyframe's."""
    counts = [n for n, _ in band_sums(truth_ns, truth_ns)]
    total = sum(counts)
    return [n / total if total else math.nan for n in counts]


def anchored_errors(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray],
                    stamps_ns: dict[int, int], mix: Sequence[float]
                    ) -> tuple[float, float, float, float]:
    """Keyframe ``poses`` scored as anchored content is, RMS: the revisit error (pairs ≥
    REVISIT_GAP_S apart), every nearby pair of distinct keyframes however close in time
    (what two devices holding these poses would score on the cross-device revisit error),
    the nearby pairs under CLOSE_S apart, and the nearby pairs' bands weighed by the frames'
    ``mix`` (frames_mix: the cross-device figure at the density of every tracked frame)."""
    keyed = {stamps_ns[i]: p for i, p in poses.items() if i in truth and i in stamps_ns}
    true = {stamps_ns[i]: truth[i] for i in poses if i in truth and i in stamps_ns}
    bands = band_sums(keyed, true)

    def rms(chosen: Sequence[tuple[int, float]]) -> float:
        n = sum(c for c, _ in chosen)
        return math.sqrt(sum(q for _, q in chosen) / n) if n else math.nan

    present = [(w, q / n) for w, (n, q) in zip(mix, bands, strict=True) if n and w > 0]
    weight = sum(w for w, _ in present)
    at_frames = math.sqrt(sum(w * mse for w, mse in present) / weight) if weight else math.nan
    return rms(bands[2:]), rms(bands), rms(bands[:1]), at_frames


def stage(name: str, poses: dict[int, np.ndarray], points: dict[int, np.ndarray],
          obs: list[Observation], k: np.ndarray, truth: dict[int, np.ndarray] | None,
          stamps_ns: dict[int, int] | None = None, mix: Sequence[float] = ()) -> Stage:
    """The row of a set of poses and points: ATE and the anchored errors against ``truth``
    (None: they are it; ``mix``: the frames' pair bands, :func:`frames_mix`)."""
    used = [ob for ob in obs if ob.point in points]
    errors = np.sqrt(reprojection_sq(poses, points, k, used))
    ate = absolute_trajectory_error(poses, truth) if truth is not None else math.nan
    anchored = (anchored_errors(poses, truth, stamps_ns, mix)
                if truth is not None and stamps_ns is not None else (math.nan,) * 4)
    return Stage(name, len(poses), len({ob.point for ob in used}), len(used), ate,
                 float(np.median(errors)), float(np.mean(errors <= INLIER_PX)), *anchored)


def floors(walk: WalkMap, gap: int, baseline_m: float, mix: Sequence[float]) -> list[Stage]:
    """The four stages of the module's docstring, the offline adjustments weighing depth with
    a virtual stereo ``baseline_m``, the anchored errors weighed by every played frame's
    pair ``mix`` (:func:`frames_mix`)."""
    m, k = walk.map, walk.intrinsics
    ids = m.keyframe_ids()
    truth = {i: walk.truth[i] for i in ids if i in walk.truth}
    obs = observations(m)
    online_poses = {i: m.keyframes[i].pose for i in ids}
    online_points = {p: pt.position for p, pt in m.points.items()}
    stamps = walk.stamps_ns
    rows = [stage("online (local BA of the newest 5)", online_poses, online_points, obs, k,
                  truth, stamps, mix)]
    print("  full bundle adjustment ...", flush=True)
    full = bundle_adjust(online_poses, online_points, obs, k, {ids[0]}, baseline_m=baseline_m,
                         max_iterations=10)
    rows.append(stage("full BA", full.poses, full.points, obs, k, truth, stamps, mix))
    print("  loop fusion ...", flush=True)
    fused_obs, merged = fuse_loops(m, full.poses, full.points, obs, k, walk.image_shape, gap)
    fused_points = {p: full.points[p] for p in {ob.point for ob in fused_obs}}
    fused = bundle_adjust(full.poses, fused_points, fused_obs, k, {ids[0]},
                          baseline_m=baseline_m, max_iterations=10)
    rows.append(stage(f"full BA, loops fused ({merged} points merged)", fused.poses,
                      fused.points, fused_obs, k, truth, stamps, mix))
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
    stamps = walk.stamps_ns
    # the nearby pairs' bands among every played frame's (the live figures' mix, by the truth
    # alone) and among the keyframes'
    shares = [frames_mix({stamps[i]: walk.truth[i] for i in ids if i in stamps and
                          i in walk.truth}) for ids in (walk.truth, walk.map.keyframe_ids())]
    rows = floors(walk, args.loop_gap, args.baseline_m, shares[0])
    camera = (f"the depth registered to {args.colour_intrinsics}" if args.colour_intrinsics
              else "the folder's own intrinsics")
    print(f"\n{args.frames} frames forward, {len(walk.map.keyframes)} keyframes, {camera}")
    print(f"nearby pairs under {CLOSE_S:g} s / {CLOSE_S:g}-{REVISIT_GAP_S:g} s / "
          f"{REVISIT_GAP_S:g} s and more apart: every frame's "
          + " / ".join(f"{100 * x:.1f} %" for x in shares[0]) + ", the keyframes' "
          + " / ".join(f"{100 * x:.1f} %" for x in shares[1]))
    print(f"revisit: keyframes ≥ {REVISIT_GAP_S:g} s apart, nearby: any two distinct "
          f"keyframes, close: nearby under {CLOSE_S:g} s apart, at the frames' mix: the "
          f"nearby pairs weighed as every frame's are; all within {REVISIT_RADIUS_M:g} m and "
          f"{REVISIT_ANGLE_DEG:g}°")
    print("| stage | keyframes | points | observations | keyframe ATE (m) | median "
          f"reprojection (px) | within {INLIER_PX:g} px | revisit RMS (m) | nearby RMS (m) | "
          "close RMS (m) | nearby at the frames' mix (m) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        cells = " | ".join("—" if math.isnan(v) else f"{v:.4f}"
                           for v in (r.revisit_m, r.nearby_m, r.close_m, r.frames_m))
        ate = "—" if math.isnan(r.ate_m) else f"{r.ate_m:.4f}"
        print(f"| {r.name} | {r.keyframes} | {r.points} | {r.observations} | {ate} | "
              f"{r.median_px:.2f} | {100 * r.within_px:.1f} % | {cells} |")
    if args.csv is not None:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            out = csv.writer(fh)
            out.writerow(["stage", "keyframes", "points", "observations", "keyframe_ate_m",
                          "median_reprojection_px", "within_3px", "revisit_rms_m",
                          "nearby_rms_m", "close_rms_m", "frames_mix_rms_m"])
            for r in rows:
                out.writerow([r.name, r.keyframes, r.points, r.observations,
                              "" if math.isnan(r.ate_m) else f"{r.ate_m:.5f}",
                              f"{r.median_px:.4f}", f"{r.within_px:.4f}",
                              "" if math.isnan(r.revisit_m) else f"{r.revisit_m:.5f}",
                              *("" if math.isnan(v) else f"{v:.5f}"
                                for v in (r.nearby_m, r.close_m, r.frames_m))])
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
