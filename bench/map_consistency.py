"""Whether the edge's map agrees with itself: the default device and edge driven in one
process over a walk that comes back, with the archive's and the map's keyframes checked
against the truth after every slot.

    python -m bench.map_consistency [SEQUENCE] [--frames 5400] [--seed 4] [--uplink lte]
        [--order forward_backward] [--vmax 15] [--loops] [--update-delay 8] [--ba-window 5]
        [--no-point-culling] [--csv FILE] [--keyframes-csv FILE]

``--order forward_backward --vmax 15`` on a dataset folder is the live ``revisit-v15`` walk
(the frames forward then back, V_max 15).

A walk that returns to a place finds it twice at the edge: in the archive (the keyframes
evicted on the way out) and in the managed map (the keyframes made on the way back, or the
archived ones restored). Where the two disagree, a loop looks too far to close and a restore
puts a second copy of the wall into the map the device tracks on. This measures that
disagreement without DDS and without threads, so a run is repeatable: each slot's
summaries, uploads and map update pass through the cores
(:func:`bench.in_process.serve_slot`), the loop closer works in the caller, and the map
update reaches the device ``--update-delay`` frames into the next slot (default 8: the
default device's D_req of 0.25 s; 0: at once — with the local adjustment the device's drift
depended on it, docs/results/map-consistency.md).

Per slot it prints (every ``--every`` slots, and at each loop) and writes to ``--csv``:

* **archive vs map** — for every archived and managed keyframe whose true poses lie within
  0.3 m and 20° (the revisit's bound), the translation error of their relative pose against
  the truth's (RMS and largest pair): how far the archive's copy of a place lies from the
  map's;
* **within the map** — the same for pairs of managed keyframes ≥ 300 frames apart (a
  restored keyframe beside the walk's own);
* the loops closed and refused and the keyframes restored so far; for each loop, how far
  apart its two keyframes truly were, how far its measured relative pose is from the truth's,
  and how far the graph's answer is from the truth against the poses before it.

At the end: the frames tracked, the device's ATE and revisit error, the loop closer's jobs
(their worker's time in all, its median and that of the last 20: an archive that grows makes
each job longer), both errors again with each
pose anchored to its keyframe (moved with that keyframe's corrections since it was published,
as AR anchors follow a map: :func:`~twinslam.live.tracking_quality.anchored_to_keyframes`),
the largest step of REP 105's odom frame beyond the truth's (the device node's
:class:`~device_tracker.odometry_frame.OdometryFrame`), the ATE of the edge's final
keyframes (archive and map), the share of the device's matches
its poses disagreed with (outliers) and the share of the final map's points with a
look-alike within 5 cm that no keyframe sees together with them (duplicates,
:mod:`twinslam.slam.duplicate_points`). ``--keyframes-csv`` writes every keyframe's history
— integrated, evicted, restored, moved by a loop — with its position then and the truth's:
where a disagreement was born.
"""

from __future__ import annotations

import argparse
import csv
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.in_process import repeatable_edge, seeded_spec, serve_slot
from device_tracker.device_core import DeviceTrackerCore
from device_tracker.odometry_frame import OdometryFrame
from device_tracker.parameters import PARAMETERS as DEVICE_PARAMETERS
from device_tracker.parameters import DeviceSettings
from edge_mapper.edge_core import EdgeMapperCore
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import (
    REVISIT_ANGLE_DEG,
    REVISIT_RADIUS_M,
    absolute_trajectory_error,
    anchored_to_keyframes,
    revisit_error,
    seen_alike,
    step_excess_mm,
    truth_in_map,
)
from twinslam.policies.registry import make_policy
from twinslam.reporting import write_dict_rows
from twinslam.rotations import rotation_angle_deg
from twinslam.sequence_player.playback import ORDERS, Playback, PlayedSequence
from twinslam.sequences.opening import AUTO, open_sequence
from twinslam.slam.back_end.loop_closing import LoopResult
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.duplicate_points import DUPLICATE_RADIUS_M, duplicate_share
from twinslam.slam.projection_matching import back_project
from twinslam.slot_protocol import default_device
from twinslam.uplink.channels import parse_channel
from twinslam.uplink.families import uplink_family

#: two managed keyframes this many frames apart that see one place: one was restored
RESTORED_GAP = 300


@dataclass(frozen=True)
class Disagreement:
    """Relative-pose errors of keyframe pairs that truly see one place (m)."""

    pairs: int = 0
    rms_m: float = math.nan
    max_m: float = math.nan
    #: the worst pair (a, b) and its error
    worst: tuple[int, int] = (-1, -1)


def disagreement(first: dict[int, np.ndarray], second: dict[int, np.ndarray],
                 truth: dict[int, np.ndarray], min_gap: int = 0) -> Disagreement:
    """For each keyframe a of ``first`` and b of ``second`` (id → camera-to-map) whose true
    poses lie within the revisit's bound and ≥ ``min_gap`` ids apart, the translation error
    of a⁻¹·b against the truth's. A relative pose needs no alignment: a map shifted as a
    whole disagrees with nothing; two copies of one place do."""
    a_ids = [k for k in first if k in truth]
    b_ids = np.array([k for k in second if k in truth], dtype=np.int64)
    if not a_ids or not len(b_ids):
        return Disagreement()
    tb = np.array([truth[int(k)] for k in b_ids])
    eb = np.array([second[int(k)] for k in b_ids])
    cos_max = math.cos(math.radians(REVISIT_ANGLE_DEG))
    errors: list[np.ndarray] = []
    pairs: list[tuple[int, int]] = []
    for a in a_ids:
        js = np.flatnonzero(seen_alike(truth[a], tb, REVISIT_RADIUS_M, cos_max)
                            & (np.abs(b_ids - a) >= max(min_gap, 1)))
        if not js.size:
            continue
        true_rel = np.linalg.inv(truth[a]) @ tb[js]
        off = np.linalg.inv(true_rel) @ (np.linalg.inv(first[a]) @ eb[js])
        errors.append(np.linalg.norm(off[:, :3, 3], axis=1))
        pairs += [(a, int(b)) for b in b_ids[js]]
    if not errors:
        return Disagreement()
    arr = np.concatenate(errors)
    return Disagreement(len(arr), float(np.sqrt(np.mean(arr ** 2))), float(arr.max()),
                        pairs[int(np.argmax(arr))])


#: what happened to one keyframe: (slot, event, its pose then), in order
History = list[tuple[int, str, np.ndarray]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default="synthetic-corridor:5400",
                        help="the walk (a sequence the player reads; default: the synthetic "
                             "corridor out and back twice)")
    parser.add_argument("--frames", type=int, default=5400, help="frames to play")
    parser.add_argument("--seed", type=int, default=4,
                        help="the uplink's seed, and a synthetic walk's (its sway and gaze)")
    parser.add_argument("--uplink", default="lte", help="uplink family (table1, lte, mmwave, "
                        "constrained)")
    parser.add_argument("--order", choices=ORDERS, default="forward",
                        help="the frames as recorded, or forward then back (a scenario's "
                             "order: the revisit walk)")
    parser.add_argument("--vmax", type=int,
                        help="V_max, keyframes the edge's map holds (default: the edge's)")
    parser.add_argument("--loops", action="store_true", help="the edge closes loops")
    parser.add_argument("--restores", type=int, default=default_device.RESTORE_KEYFRAMES,
                        help="archived keyframes restored a slot where the camera heads")
    parser.add_argument("--update-delay", type=int, default=8,
                        help="frames of the next slot the device tracks before the map update "
                             "reaches it (default 8: the default device's D_req of 0.25 s, as "
                             "a live update arrives; 0: at once)")
    parser.add_argument("--ba-window", type=int, default=BackEndConfig().ba_window,
                        help="keyframes the edge's local bundle adjustment moves (0: none)")
    parser.add_argument("--point-culling", action=argparse.BooleanOptionalAction,
                        default=BackEndConfig().point_culling,
                        help="the edge removes map points later keyframes never find again")
    parser.add_argument("--integration-fusion", action=argparse.BooleanOptionalAction,
                        default=BackEndConfig().integration_fusion,
                        help="a new keyframe's feature beside a map point that looks alike "
                             "observes it instead of making a copy")
    parser.add_argument("--every", type=int, default=10, help="print every N slots")
    parser.add_argument("--csv", type=Path, help="write the per-slot figures here")
    parser.add_argument("--keyframes-csv", type=Path,
                        help="write every keyframe's history (events and errors) here")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    spec = seeded_spec(args.sequence, args.seed)
    source = open_sequence(spec, end=args.frames, colour_intrinsics=AUTO)
    reader = PlayedSequence(source, Playback(args.order))
    device_params = {p.name: p.default for p in DEVICE_PARAMETERS}
    settings = DeviceSettings.from_parameters(device_params)
    DeviceTrackerCore.warm_up(source.intrinsics)
    device = DeviceTrackerCore(source.intrinsics, settings.slot_frames, settings.tracking,
                               settings.keep_slots, settings.frame_rate_hz, settings.map_source,
                               settings.own_map_after)
    config = repeatable_edge(loop_closing=args.loops, restore_keyframes=args.restores,
                             ba_window=args.ba_window, point_culling=args.point_culling,
                             integration_fusion=args.integration_fusion,
                             **({} if args.vmax is None else {"vmax": args.vmax}))
    family = uplink_family(args.uplink)
    channel = parse_channel(family.channel, family.rate_mbps or (5.0, 45.0), seed=args.seed,
                            slot_seconds=settings.slot_frames / settings.frame_rate_hz)
    truth: dict[int, np.ndarray] = {}
    poses: dict[int, np.ndarray] = {}
    tracked: list[int] = []
    stamp_ns: dict[int, int] = {}
    matches = inliers = 0              #: the device's, over the frames its motion model posed
    history: dict[int, History] = {}
    rows: list[dict[str, object]] = []
    disagreements: list[Disagreement] = []      #: archive vs map, each slot
    #: every keyframe's pose (archive and map) at each slot's end, and the slot a frame was
    #: tracked in: what a frame's anchor keyframe looked like when the frame was published
    keyframes_then: list[dict[int, np.ndarray]] = []
    slot_of: dict[int, int] = {}
    #: REP 105's odom frame as the device node would publish it (the map pose's corrections
    #: taken out): its position per tracked frame
    odometry = OdometryFrame()
    odom: dict[int, np.ndarray] = {}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        edge = EdgeMapperCore(make_policy(default_device.POLICY), source.intrinsics, config,
                              Path(tmp) / "edge.npz")
        restored_total = 0
        held = None
        taken: list[LoopResult] = []
        take = edge.loop_closer.take

        def keep(wait_s: float = 0.0) -> LoopResult | None:
            result = take(wait_s)
            if result is not None and result.closure is not None:
                taken.append(result)
            return result

        edge.loop_closer.take = keep  # type: ignore[method-assign]
        for frame in reader:
            result = device.track(frame.color, frame.depth, frame.stamp)
            record = result.record
            in_odom, _ = odometry.update(record.pose, record.tracked, record.map_version,
                                         record.relocalised)
            if held is not None and (result.slot_done or
                                     frame.index - held[2] >= args.update_delay):
                device.apply_map_update(held[0], held[1])
                held = None
            if frame.pose is not None:
                truth[frame.index] = frame.pose
                stamp_ns[frame.index] = round(frame.stamp * 1e9)
                if record.tracked:
                    poses[frame.index] = record.pose
                    odom[frame.index] = in_odom[:3, 3]
                    tracked.append(frame.index)
                    slot_of[frame.index] = len(keyframes_then)
            if record.tracked and not record.relocalised:
                matches += record.matches
                inliers += record.inliers
            if not result.slot_done:
                continue
            state, rate = channel.step()
            before = {k: kf.pose.copy() for k, kf in edge.map.keyframes.items()}
            served = serve_slot(device, edge, rate, state, hold=args.update_delay > 0)
            out = served.outcome
            if served.update is not None:
                held = (served.update, out.slot, frame.index)
            restored_total += len(out.restored)
            for k in out.integrated:
                if k in edge.map.keyframes:
                    history.setdefault(k, []).append(
                        (out.slot, "integrated", edge.map.keyframes[k].pose.copy()))
            for k in out.evicted:
                history.setdefault(k, []).append(
                    (out.slot, "evicted", before.get(k, np.full((4, 4), np.nan))))
            for k in out.restored:
                history.setdefault(k, []).append(
                    (out.slot, "restored", edge.map.keyframes[k].pose.copy()))
            if out.loop is not None and not out.loop.refused:
                for k, kf in edge.map.keyframes.items():
                    history.setdefault(k, []).append(
                        (out.slot, "loop", kf.pose.copy()))
            archived = {kf.id: kf.pose for kf in edge.archive}
            managed = {k: kf.pose for k, kf in edge.map.keyframes.items()}
            keyframes_then.append({**archived, **managed})
            across = disagreement(archived, managed, truth)
            disagreements.append(across)
            within = disagreement(managed, managed, truth, RESTORED_GAP)
            row = {"slot": out.slot, "frame": frame.index, "map": len(managed),
                   "archive": len(archived), "restored": restored_total,
                   "loops_closed": edge.loops_closed, "loops_refused": edge.loops_refused,
                   "loop": "" if out.loop is None else
                   f"{out.loop.old}->{out.loop.new} {out.loop.inliers} inl "
                   f"{out.loop.moved_m:.3f} m {out.loop.refused or 'applied'}",
                   "archive_pairs": across.pairs, "archive_rms_m": across.rms_m,
                   "archive_max_m": across.max_m, "archive_worst": across.worst,
                   "map_pairs": within.pairs, "map_rms_m": within.rms_m,
                   "map_max_m": within.max_m, "map_worst": within.worst,
                   "edge_ms": served.plan_ms + served.integrate_ms + served.finish_ms}
            rows.append(row)
            if out.loop is not None and taken:
                print(loop_report(edge, taken[-1], truth, source.intrinsics))
            if out.slot % args.every == 0 or out.loop is not None:
                print(f"slot {out.slot:4d} frame {frame.index:5d} map {len(managed):2d} "
                      f"archive {len(archived):3d} restored {restored_total:3d} "
                      f"loops {edge.loops_closed}/{edge.loops_refused} | archive vs map "
                      f"{across.pairs:4d} pairs rms {across.rms_m:.3f} max {across.max_m:.3f} "
                      f"{across.worst} | within map {within.pairs:3d} rms {within.rms_m:.3f} "
                      f"max {within.max_m:.3f} {within.worst} {row['loop']}", flush=True)
        edge.close()
        points = list(edge.map.points.values())
        duplicates = duplicate_share(np.array([p.position for p in points]).reshape(-1, 3),
                                     np.array([p.descriptor for p in points]).reshape(-1, 32),
                                     [p.observers for p in points])
        final = {kf.id: kf.pose for kf in edge.archive}
        final.update({k: kf.pose for k, kf in edge.map.keyframes.items()})
    ate = absolute_trajectory_error(poses, truth)
    stamps = {stamp_ns[k]: k for k in tracked}
    truth_by_stamp = {s: truth[k] for s, k in stamps.items()}
    rev = revisit_error({s: poses[k] for s, k in stamps.items()}, truth_by_stamp, stamps)
    last = len(keyframes_then) - 1
    anchored = anchored_to_keyframes({k: poses[k] for k in tracked},
                                     {k: keyframes_then[min(slot_of[k], last)] for k in tracked},
                                     final)
    rev_anchored = revisit_error({s: anchored[k] for s, k in stamps.items()}, truth_by_stamp,
                                 stamps)
    print(f"{len(tracked)} of {len(truth)} frames tracked, ATE {ate:.3f} m, revisit error "
          f"RMS {rev.rms_m:.3f} m ({rev.pairs} pairs), loops {edge.loops_closed} closed "
          f"{edge.loops_refused} refused, {time.perf_counter() - started:.0f} s")
    jobs = list(edge.back_end.loop_closer.job_seconds)
    if jobs:
        print(f"the loop closer: {len(jobs)} jobs, {sum(jobs):.1f} s on its worker, median "
              f"{np.median(jobs) * 1e3:.0f} ms, the last 20 jobs' median "
              f"{np.median(jobs[-20:]) * 1e3:.0f} ms")
    print(f"anchored to the keyframes (each pose moved with its keyframe's corrections since): "
          f"ATE {absolute_trajectory_error(anchored, truth):.3f} m, revisit error RMS "
          f"{rev_anchored.rms_m:.3f} m")
    print(f"the odom frame: its largest step beyond the truth's "
          f"{step_excess_mm(odom, {k: truth[k][:3, 3] for k in tracked}, tracked):.1f} mm "
          f"({odometry.corrections} frames corrected)")
    print(f"the edge's final keyframes (archive and map, {len(final)}): ATE "
          f"{absolute_trajectory_error(final, truth):.3f} m")
    print(f"the device's matches: {1 - inliers / max(matches, 1):.1%} outliers; the edge's map "
          f"at the end: {len(edge.map.points)} points, {duplicates:.1%} with a look-alike "
          f"within {DUPLICATE_RADIUS_M * 100:.0f} cm no keyframe sees with it")
    largest = max((d.max_m for d in disagreements if not math.isnan(d.max_m)), default=math.nan)
    print(f"archive vs map: at the end RMS {disagreements[-1].rms_m:.3f} m, the largest "
          f"pair over the walk {largest:.3f} m")
    if args.csv:
        write_dict_rows(args.csv, rows)
    if args.keyframes_csv:
        write_histories(args.keyframes_csv, history, truth)


def loop_report(edge: EdgeMapperCore, result: LoopResult, truth: dict[int, np.ndarray],
                intrinsics: np.ndarray) -> str:
    """A loop against the truth: how far apart its keyframes were, how far its measurement
    is from the truth's relative pose, what the graph did to the keyframes' error, and how
    well the old keyframe's points still fit its own measurements."""
    q, o, measured = result.query, result.candidate.old, result.candidate.measured
    if q not in truth or o not in truth or measured is None or result.closure is None:
        return f"    loop {o}->{q}: no truth for it"
    true_rel = np.linalg.inv(truth[o]) @ truth[q]
    off = np.linalg.inv(true_rel) @ measured
    turn = rotation_angle_deg(off[:3, :3])
    return (f"    loop {o}->{q}: truly {np.linalg.norm(true_rel[:3, 3]):.2f} m apart; measured "
            f"off by {np.linalg.norm(off[:3, 3]):.3f} m, {turn:.2f} deg; graph error "
            f"{result.closure.initial_error:.1f} -> {result.closure.final_error:.1f}\n"
            f"    loop {o}->{q}: keyframes against the truth {graph_vs_truth(result, truth)}\n"
            f"    loop {o}->{q}: the old keyframe against its points "
            f"{self_disagreement(edge, o, intrinsics)}")


def graph_vs_truth(result: LoopResult, truth: dict[int, np.ndarray]) -> str:
    """RMS and largest position error of the loop graph's keyframes against the truth, before
    and after the graph (each aligned to the truth on its own, as the ATE)."""
    closure = result.closure
    if closure is None:
        return ""
    ids = [k for k in sorted(closure.poses) if k in truth]
    after = {k: closure.poses[k] for k in ids}
    before = {k: np.linalg.inv(closure.corrections[k]) @ closure.poses[k] for k in ids}
    out = []
    for name, poses in (("before", before), ("after", after)):
        in_map = truth_in_map(poses, {k: truth[k] for k in ids})
        e = np.array([np.linalg.norm(poses[k][:3, 3] - in_map[k][:3, 3]) for k in ids])
        worst = ids[int(np.argmax(e))]
        out.append(f"{name} rms {np.sqrt(np.mean(e ** 2)):.3f} max {e.max():.3f} ({worst})")
    return "; ".join(out)


def self_disagreement(edge: EdgeMapperCore, kf_id: int, intrinsics: np.ndarray) -> str:
    """How far keyframe ``kf_id``'s own measurements (lifted by its pose) lie from the
    points it observes: median and 90th percentile (m), and the share beyond 5 cm."""
    if kf_id in edge.archive:
        kf = edge.archive.get(kf_id)
        pose, positions, meas = kf.pose, kf.positions, kf.measurements
    elif kf_id in edge.map.keyframes:
        k = edge.map.keyframes[kf_id]
        ids = sorted(k.points)
        pose = k.pose
        positions = np.array([edge.map.points[p].position for p in ids])
        meas = np.array([k.measurements[p] for p in ids])
    else:
        return "gone"
    ok = np.isfinite(meas).all(axis=1) & (meas[:, 2] > 0)
    seen = back_project(meas[ok, :2], meas[ok, 2], intrinsics, pose)
    d = np.linalg.norm(seen - positions[ok], axis=1)
    if not len(d):
        return "no depth"
    return (f"median {np.median(d):.3f} p90 {np.percentile(d, 90):.3f} m, "
            f"{np.mean(d > 0.05):.0%} beyond 5 cm of {len(d)}")


def write_histories(path: Path, history: dict[int, History],
                    truth: dict[int, np.ndarray]) -> None:
    """Each keyframe's events with its position then and the truth's."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["keyframe", "slot", "event", "x", "y", "z", "true_x", "true_y",
                         "true_z"])
        for k in sorted(history):
            t = truth.get(k, np.full((4, 4), np.nan))
            for slot, event, pose in history[k]:
                writer.writerow([k, slot, event, *np.round(pose[:3, 3], 4),
                                 *np.round(t[:3, 3], 4)])


if __name__ == "__main__":
    main()
