"""The report of one live run: mean υ, lost share, ATE/RPE (evo), uploads, the device's
failures and relocalisations, the edge's milliseconds per slot — computed from what the monitor
heard, and printed as a table."""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from twinslam_msgs.msg import MapStats

from msg_schemas.headers import time_key, time_seconds
from twinslam.live.run_log import RunLog
from twinslam.live.tracking_quality import (
    FrameFlags,
    Jitter,
    TrackingEvents,
    absolute_trajectory_error,
    anchored_to_keyframes,
    jitter,
    jump_count,
    relative_pose_error,
    revisit_error,
    step_excess_mm,
    tracking_events,
    translation_errors,
)
from twinslam.policies.registry import LEARNED_PREFIX
from twinslam.slam.duplicate_points import duplicate_share
from twinslam.slam.map_update import MapSnapshot


@dataclass
class RunReport:
    policy: str
    slots: int
    mean_uncertainty: float          #: mean υ over slots, a lost next-slot frame scoring 0
    lost_share: float                #: mean share of next-slot frames MapStats calls lost
    tracked_uncertainty: float       #: mean υ over slots, tracked next-slot frames only
    ate_m: float                     #: NaN without ground truth
    rpe_m: float                     #: over 1 s (30 frames); NaN without ground truth
    frames_uploaded: int
    bytes_uploaded: int              #: keyframes and relocalisation requests
    achieved_mbps: float             #: mean over slots with uploads
    untracked_frames: int
    tracking_failures: int           #: tracked → untracked transitions
    relocalisations: int             #: frames tracked again by relocalisation
    recover_s: float                 #: mean seconds from a loss to tracking again (NaN: none)
    edge_ms_median: float
    seconds: float
    #: which policy decided how many slots (``UploadRequest.policy``), in the order they first
    #: decided, e.g. "adapt (fallback):2, mbrl:amm.pt:28" — a learned policy's fallback and a
    #: policy set during the run (``ros2 param set``) show here
    decided_by: str = ""
    #: camera frames missing from the device's complete slots, the player's skipped ones left
    #: out: a device that fell behind the camera (an overloaded machine) shows here
    frames_dropped: int = 0
    #: published tracked poses whose aligned error rose by more than ``JUMP_M`` from the
    #: one before
    #: (:func:`~twinslam.live.tracking_quality.jump_count`; NaN: no ground truth). Runs of
    #: versions before it counted only relocalisations landing that far off
    jumps: float = math.nan
    #: the share of the device's frames it did not track (NaN: no frames)
    failed_share: float = math.nan
    #: the 95th percentile and the longest of its losses, seconds without a pose (0: none)
    loss_p95_s: float = math.nan
    longest_loss_s: float = math.nan
    #: the device's CPU time a frame (its tracking thread; NaN: not reported)
    device_cpu_ms: float = math.nan
    #: what the edge sent the device, MB (map updates, relocalisation answers)
    downlink_mb: float = math.nan
    #: archived keyframes the edge brought back into the map over the run (NaN: not reported)
    restores: float = math.nan
    #: the largest aligned error of a published tracked pose, m (NaN: no ground truth)
    max_error_m: float = math.nan
    #: the published position's shake over tracked frames, mm (:class:`~twinslam.live.
    #: tracking_quality.Jitter`), the frames over 20 mm, and the truth's RMS over the same
    jitter_rms_mm: float = math.nan
    jitter_median_mm: float = math.nan
    jitter_p95_mm: float = math.nan
    jitter_over_20mm: float = math.nan
    truth_jitter_rms_mm: float = math.nan
    #: frames whose solved pose a gate refused (an impossible motion, a relocalisation the
    #: pose gate refused), and uploads the edge's keyframe gate refused
    poses_refused: float = math.nan
    keyframes_refused: float = math.nan
    #: the longest run of slots in which the device uploaded no keyframe (NaN: no slot)
    longest_no_upload_slots: float = math.nan
    #: frames the player could not read (a corrupt or empty image) and left out, as it said
    #: on /diagnostics (NaN: it said nothing)
    frames_skipped: float = math.nan
    #: how far an anchor placed on a first visit appears moved on the return, RMS over the
    #: run's revisits, m (:class:`~twinslam.live.tracking_quality.RevisitError`), and how many
    #: pairs of frames revisit a place (NaN: no ground truth)
    revisit_error_m: float = math.nan
    revisit_pairs: float = math.nan
    #: REP 105's odom frame (device/odom): the RMS jitter of its positions over tracked
    #: frames, mm, and its largest frame-to-frame step beyond the truth's, mm (NaN: no odom,
    #: or no ground truth for the step)
    odom_jitter_rms_mm: float = math.nan
    odom_step_excess_mm: float = math.nan
    #: the share of the tracked frames whose pose came from PnP RANSAC because the motion
    #: model's refinement kept too few of its matches against the map: matches that disagree
    #: (a map inconsistent with itself, duplicated points, a motion the model missed); NaN:
    #: nothing tracked
    pnp_ransac_share: float = math.nan
    #: loops the edge closed over the run (``loop_closing``), and the loop closer's mean time
    #: on one, ms, off the slot's critical path (NaN: no loop closed, or not reported)
    loops_closed: float = math.nan
    loop_closing_ms: float = math.nan
    #: the share of the device's matches against its map that its pose disagreed with (1 −
    #: inliers / matches over the frames the motion model tracked): a map inconsistent with
    #: itself shows here (NaN: none tracked, or a device that did not report its matches)
    outlier_share: float = math.nan
    #: loops the edge found but refused over the run: their corrections would have moved the
    #: map farther than a device accepts (NaN: not reported)
    loops_refused: float = math.nan
    #: the share of the map's points with a look-alike within 5 cm (one corner twice: the
    #: device's matches split between copies), over the map updates the device received
    #: (:mod:`twinslam.slam.duplicate_points`; NaN: none received)
    duplicate_share: float = math.nan
    #: the revisit error with each published pose anchored to its keyframe, moved with the
    #: corrections the map updates later gave that keyframe (AR anchors follow a map this
    #: way; a loop's correction then no longer counts as the device coming back elsewhere:
    #: :func:`~twinslam.live.tracking_quality.anchored_to_keyframes`); m, NaN: no ground truth
    anchored_revisit_error_m: float = math.nan
    #: the ATE of the published poses anchored so: the trajectory as the edge's final map
    #: has it (ORB-SLAM's saved trajectory), where ``ate_m`` is the poses as published then
    anchored_ate_m: float = math.nan
    #: uploads asked for that were not in when their slot closed (MapStats'
    #: ``missing_keyframes``: frames the device no longer held, or keyframes lost or late)
    keyframes_missing: float = math.nan
    #: slots after the first whose edge map was in pieces (MapStats' ``uncertainty`` +inf:
    #: keyframes that share no point with the rest, e.g. made in a fast turn). Every frame of
    #: such a slot scores as lost, whatever the device tracked (docs/architecture.md §2), so
    #: a lost share beside none untracked reads here (NaN: no slot after the first)
    map_in_pieces_slots: float = math.nan

    ROW = ("{label:<14} {mean_uncertainty:>10.1f} {lost_share:>6.1%} "
           "{tracked_uncertainty:>10.1f} {ate_m:>7.3f} "
           "{rpe_m:>7.3f} {frames_uploaded:>7d} {mbytes:>7.1f} {achieved_mbps:>7.1f} "
           "{untracked_frames:>6d} {failed_share:>6.1%} {tracking_failures:>5d} "
           "{relocalisations:>6d} {jumps:>5.0f} {max_error_m:>7.3f} {jitter_rms_mm:>7.1f} "
           "{truth_jitter_rms_mm:>7.1f} {odom_jitter_rms_mm:>7.1f} {odom_step_excess_mm:>7.1f} "
           "{revisit_error_m:>7.3f} {anchored_revisit_error_m:>7.3f} "
           "{pnp_ransac_share:>6.1%} {outlier_share:>6.1%} "
           "{duplicate_share:>6.1%} "
           "{restores:>6.0f} "
           "{loops_closed:>5.0f} {map_in_pieces_slots:>6.0f} "
           "{recover_s:>7.2f} "
           "{loss_p95_s:>7.2f} {longest_loss_s:>7.2f} {downlink_mb:>7.1f} {device_cpu_ms:>7.1f} "
           "{edge_ms_median:>7.0f} {longest_no_upload_slots:>5.0f} {dropped:>7} "
           "{frames_skipped:>7.0f}")
    HEADER = (f"{'policy':<14} {'mean υ':>10} {'lost':>6} {'υ tracked':>10} {'ATE m':>7} "
              f"{'RPE m':>7} "
              f"{'uploads':>7} {'MB':>7} {'Mbit/s':>7} {'untrk':>6} {'failed':>6} "
              f"{'fails':>5} {'reloc':>6} {'jumps':>5} {'max e m':>7} {'jit mm':>7} "
              f"{'gt jit':>7} {'odo jit':>7} {'odo st':>7} {'revis m':>7} {'anchor':>7} "
              f"{'ransac':>6} "
              f"{'outl':>6} {'dupl':>6} "
              f"{'restor':>6} {'loops':>5} {'pieces':>6} "
              f"{'recov s':>7} {'p95 s':>7} "
              f"{'max s':>7} {'down MB':>7} {'dev ms':>7} {'edge ms':>7} {'no up':>5} "
              f"{'dropped':>7} {'skipped':>7}")

    @property
    def label(self) -> str:
        """The policy as the table shows it (:func:`policy_label`); a run whose policy was
        changed while it ran names each one that decided, in order: ``lff→pu``."""
        others = [p for p in decided_policies(self.decided_by)
                  if p != self.policy and not p.endswith(FALLBACK)]
        return "→".join(policy_label(p) for p in [self.policy, *others])

    @property
    def dropped_cell(self) -> str:
        """The camera frames the device dropped as a table shows them, ``!`` marking any: it
        fell behind its camera, the machine was short of CPU, and the figures measure that
        too."""
        return f"{self.frames_dropped}{'!' if self.frames_dropped else ''}"

    def pieces_line(self, name: str) -> str | None:
        """What a lost share owes to a map in pieces, said under the table for run or device
        ``name`` (None: its map never was): the column alone reads as a count, and a lost
        share with no frame untracked reads as a device that lost frames."""
        if not self.map_in_pieces_slots > 0:          # NaN too
            return None
        return (f"{name}: the edge's map was in pieces (u(G) = +inf) in "
                f"{self.map_in_pieces_slots:.0f} of its {self.slots - 1} slots after the "
                f"first; every frame of those slots counts as lost whatever the device tracked "
                f"(lost {self.lost_share:.1%}, {self.untracked_frames} frames untracked)")

    def row(self) -> str:
        """The run's line of the table."""
        return self.ROW.format(mbytes=self.bytes_uploaded / 1e6, label=self.label,
                               dropped=self.dropped_cell, **self.__dict__)


def policy_label(policy: str) -> str:
    """A policy as tables and file names show it: a learned one (``mbrl:CHECKPOINT``) by its
    checkpoint's file name, ``mbrl:amm_s0``; any other as it is named (``mpc:H=2/S=1``)."""
    kind, sep, path = policy.partition(":")
    return f"{kind}:{Path(path).stem}" if sep and kind == LEARNED_PREFIX else policy


def record_events(record: RunLog) -> TrackingEvents:
    """The device's tracking failures and relocalisations, from its frame summaries."""
    return tracking_events(FrameFlags(time_seconds(f.stamp), bool(f.tracked), bool(f.relocalised))
                           for s in record.summaries.values() for f in s.frames)


def _finite_mean(values: Iterable[float]) -> float:
    """Mean of the finite values (NaN: the edge did not know, or nothing was tracked)."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def in_final_frame(record: RunLog) -> dict[int, np.ndarray]:
    """The published poses (stamp ns → camera-to-map), each tracked on a map in a frame the
    device's map later left — merged into another device's, the map update's header naming
    that device's frame — carried by the merge's motion (the frame correction's change at the
    first map version in the new frame) into the frame the device ended in. A merge moves the
    map's coordinates, not the device: left in, every figure that aligns the walk once, or
    follows its poses frame to frame, would count the distance between the two frames as the
    device's error."""
    snapshots = sorted(record.maps.values(), key=lambda m: m.version)
    merges = [(now.version, now.frame_correction @ np.linalg.inv(before.frame_correction))
              for before, now in itertools.pairwise(snapshots)
              if before.frame_id and now.frame_id and before.frame_id != now.frame_id]
    if not merges:
        return record.poses
    version = {time_key(f.stamp): int(f.map_version)
               for s in record.summaries.values() for f in s.frames}
    carried = {}
    for stamp, pose in record.poses.items():
        tracked_on = version.get(stamp, -1)
        for first, motion in merges:
            if tracked_on < first:
                pose = motion @ pose
        carried[stamp] = pose
    return carried


def report(policy: str, record: RunLog, seconds: float, slot_frames: int) -> RunReport:
    """What the run measured; ``slot_frames``: the device's F, to count dropped frames. The
    poses are judged in the frame the device ended in (:func:`in_final_frame`); the anchored
    figures follow the keyframes, which carry a merge by themselves."""
    published = record
    record = dataclasses.replace(record, poses=in_final_frame(record))
    stats = [record.stats[s] for s in sorted(record.stats)]
    scored = stats[1:]         # slot 0 plans against an empty map: every policy loses it all
    tps = [t for t in record.throughput.values() if t.frames_sent]
    events = record_events(record)
    # the tracked poses' errors, after the alignment ATE makes of every published pose (an
    # untracked frame's pose is the motion model's guess, published but flagged)
    tracked = tracked_stamps(record)
    errors = {s: e for s, e in translation_errors(record.poses, record.ground_truth).items()
              if s in tracked}
    jitter_rms, jitter_median, jitter_p95, jitter_over, truth_jitter = \
        _jitter_cells(record, tracked)
    revisit_m, revisit_pairs = _revisit_cells(record, tracked)
    odom_jitter, odom_step = _odom_cells(record, tracked)
    loops_closed, loop_ms = _loop_cells(stats)
    anchored_ate, anchored_revisit = anchored_cells(published, tracked)
    throughput = record.throughput.values()
    return RunReport(
        policy=policy, slots=len(stats),
        mean_uncertainty=_finite_mean(s.mean_uncertainty for s in scored),
        lost_share=float(np.mean([s.lost_share for s in scored])) if scored else 0.0,
        tracked_uncertainty=_finite_mean(s.tracked_uncertainty for s in scored),
        ate_m=absolute_trajectory_error(record.poses, record.ground_truth),
        rpe_m=relative_pose_error(record.poses, record.ground_truth),
        frames_uploaded=sum(int(t.frames_sent) for t in throughput),
        # keyframes and the relocalisation requests the link carried
        bytes_uploaded=sum(int(t.bytes_sent) + int(t.request_bytes) for t in throughput),
        achieved_mbps=float(np.mean([t.achieved_mbps for t in tps])) if tps else 0.0,
        untracked_frames=events.untracked, tracking_failures=events.failures,
        relocalisations=events.relocalisations, recover_s=events.mean_recover_s,
        edge_ms_median=float(np.median([s.slot_processing_ms for s in stats])) if stats
        else math.nan,
        seconds=seconds, decided_by=deciders(record),
        frames_dropped=dropped_frames(record, slot_frames, record.frames_skipped or 0),
        jumps=float(jump_count(errors)) if errors else math.nan,
        failed_share=events.failed_share, loss_p95_s=events.loss_p95_s,
        longest_loss_s=events.longest_loss_s, device_cpu_ms=device_cpu_ms(record),
        downlink_mb=record.downlink_bytes / 1e6,
        restores=float(sum(int(s.restored_keyframes) for s in stats)),
        max_error_m=max(errors.values()) if errors else math.nan,
        jitter_rms_mm=jitter_rms, jitter_median_mm=jitter_median, jitter_p95_mm=jitter_p95,
        jitter_over_20mm=jitter_over, truth_jitter_rms_mm=truth_jitter,
        poses_refused=float(sum(bool(f.pose_refused) for s in record.summaries.values()
                                for f in s.frames)),
        keyframes_refused=float(sum(int(s.refused_keyframes) for s in stats)),
        longest_no_upload_slots=longest_without_upload(record),
        frames_skipped=math.nan if record.frames_skipped is None
        else float(record.frames_skipped),
        revisit_error_m=revisit_m, revisit_pairs=revisit_pairs,
        odom_jitter_rms_mm=odom_jitter, odom_step_excess_mm=odom_step,
        pnp_ransac_share=pnp_ransac_share(record), loops_closed=loops_closed,
        loop_closing_ms=loop_ms, outlier_share=outlier_share(record),
        loops_refused=float(max(int(s.loops_refused) for s in stats)) if stats else math.nan,
        duplicate_share=map_duplicate_share(record),
        anchored_revisit_error_m=anchored_revisit, anchored_ate_m=anchored_ate,
        keyframes_missing=float(sum(int(s.missing_keyframes) for s in stats)),
        map_in_pieces_slots=float(sum(1 for s in scored if s.uncertainty == math.inf))
        if scored else math.nan)


def map_duplicate_share(record: RunLog) -> float:
    """The duplicate share of every slot's map update, points of all of them counted together
    (NaN: no map update)."""
    maps = [m for m in record.maps.values() if len(m.positions)]
    if not maps:
        return math.nan
    shares = [duplicate_share(m.positions, m.descriptors, _seen_by(m)) for m in maps]
    return float(np.average(shares, weights=[len(m.positions) for m in maps]))


def _seen_by(snapshot: MapSnapshot) -> list[set[int]] | None:
    """Each point's keyframes (by index) in a map update (None: it lists none)."""
    if not snapshot.keyframe_points:
        return None
    row = {int(p): i for i, p in enumerate(snapshot.point_ids)}
    seen: list[set[int]] = [set() for _ in snapshot.point_ids]
    for k, points in enumerate(snapshot.keyframe_points):
        for p in np.asarray(points).tolist():
            if (i := row.get(int(p))) is not None:
                seen[i].add(k)
    return seen


def outlier_share(record: RunLog) -> float:
    """1 − inliers / matches over the tracked frames that were not relocalised (NaN: none,
    or no matches reported)."""
    frames = [f for s in record.summaries.values() for f in s.frames
              if f.tracked and not f.relocalised]
    matches = sum(int(f.matches) for f in frames)
    return 1.0 - sum(int(f.inliers) for f in frames) / matches if matches else math.nan


def _loop_cells(stats: list[MapStats]) -> tuple[float, float]:
    """(loops the edge closed, its mean ms on one) from its MapStats (no slot: NaN, NaN; no
    loop: 0, NaN)."""
    if not stats:
        return math.nan, math.nan
    times = [float(s.loop_closing_ms) for s in stats if s.loop_closing_ms > 0]
    return float(max(int(s.loops_closed) for s in stats)), \
        float(np.mean(times)) if times else math.nan


def pnp_ransac_share(record: RunLog) -> float:
    """The share of the tracked frames whose pose fell back to PnP RANSAC (NaN: none
    tracked)."""
    tracked = [bool(f.pnp_ransac) for s in record.summaries.values() for f in s.frames
               if f.tracked]
    return float(np.mean(tracked)) if tracked else math.nan


def _odom_cells(record: RunLog, tracked: set[int]) -> tuple[float, float]:
    """(RMS jitter, largest step beyond the truth's) of the odom positions of tracked
    frames, mm; NaN without device/odom."""
    odom = {s: p[:3, 3] for s, p in record.odom_poses.items() if s in tracked}
    if not odom:
        return math.nan, math.nan
    stamps = frame_stamps(record)
    truth = {s: record.ground_truth[s][:3, 3] for s in odom if s in record.ground_truth}
    return jitter(odom, stamps).rms_mm, step_excess_mm(odom, truth, stamps)


def _revisit_cells(record: RunLog, tracked: set[int]) -> tuple[float, float]:
    """(RMS revisit error m, revisits) of the tracked poses; NaN without ground truth."""
    if not record.ground_truth:
        return math.nan, math.nan
    revisits = revisit_error(record.poses, record.ground_truth, tracked)
    return revisits.rms_m, float(revisits.pairs)


def anchored_poses(record: RunLog) -> dict[int, np.ndarray]:
    """Every published pose (stamp ns → camera-to-map) anchored to the keyframes of the map
    its frame was tracked against (the newest update of its version or before), moved to
    where the edge held those keyframes last (:func:`final_keyframe_poses`): the trajectory
    ORB-SLAM saves (each frame relative to its reference keyframe, composed with that
    keyframe's final pose), which a loop's later correction reaches."""
    snapshots = sorted(record.maps.values(), key=lambda m: m.version)
    versions = [m.version for m in snapshots]
    keyframes = [dict(zip(m.keyframe_ids.tolist(), m.keyframe_poses, strict=True))
                 for m in snapshots]
    frames = {int(f.frame_id): (time_key(f.stamp), int(f.map_version))
              for s in record.summaries.values() for f in s.frames}
    now = final_keyframe_poses(record, {stamp: fid for fid, (stamp, _) in frames.items()})
    published = {fid: record.poses[stamp] for fid, (stamp, _) in frames.items()
                 if stamp in record.poses}
    then: dict[int, dict[int, np.ndarray]] = {}
    for fid in published:
        at = bisect.bisect_right(versions, frames[fid][1]) - 1
        if at >= 0:
            then[fid] = keyframes[at]
    anchored = anchored_to_keyframes(published, then, now)
    return {frames[fid][0]: pose for fid, pose in anchored.items()}


def anchored_cells(record: RunLog, tracked: set[int]) -> tuple[float, float]:
    """(ATE, RMS revisit error of the tracked frames) of :func:`anchored_poses`, m; NaN
    without ground truth."""
    if not record.ground_truth:
        return math.nan, math.nan
    anchored = anchored_poses(record)
    return (absolute_trajectory_error(anchored, record.ground_truth),
            revisit_error(anchored, record.ground_truth, tracked).rms_m)


def final_keyframe_poses(record: RunLog, frame_of: dict[int, int]) -> dict[int, np.ndarray]:
    """Each keyframe's last pose at the edge (id → camera-to-map): the map updates and the
    newest keyframe trajectory applied in the order the edge stamped them (a map update and
    the trajectory of one slot share its stamp; the trajectory, sent after, wins). Map updates
    alone miss a keyframe a loop corrected after it left the map; ``frame_of`` (capture stamp
    ns → frame id) names the trajectory's keyframes."""
    now: dict[int, np.ndarray] = {}

    def apply_maps(keep: Callable[[int], bool]) -> None:
        for slot, snapshot in sorted(record.maps.items(), key=lambda kv: kv[1].version):
            if keep(record.map_stamps.get(slot, -1)):
                now.update(zip(snapshot.keyframe_ids.tolist(), snapshot.keyframe_poses,
                               strict=True))

    sent = record.trajectory_stamp
    apply_maps(lambda stamp: stamp <= sent)
    now.update((frame_of[s], pose) for s, pose in record.keyframe_trajectory.items()
               if s in frame_of)
    apply_maps(lambda stamp: stamp > sent)
    return now


def longest_without_upload(record: RunLog) -> float:
    """The longest run of the device's slots in which it sent no keyframe (a slot whose
    throughput report never came sent none); NaN without slots."""
    slots = sorted(record.summaries)
    if not slots:
        return math.nan
    longest = run = 0
    for slot in slots:
        sent = record.throughput.get(slot)
        run = 0 if sent is not None and sent.frames_sent > 0 else run + 1
        longest = max(longest, run)
    return float(longest)


def tracked_stamps(record: RunLog) -> set[int]:
    """The stamps (ns) of the frames the device counted as tracked."""
    return {time_key(f.stamp) for s in record.summaries.values() for f in s.frames
            if f.tracked}


def frame_stamps(record: RunLog) -> list[int]:
    """The stamps (ns) of every frame the device tracked or lost, in frame order: the
    consecutive frames jitter is measured over."""
    frames = sorted((int(f.frame_id), time_key(f.stamp)) for s in record.summaries.values()
                    for f in s.frames)
    return [stamp for _, stamp in frames]


def run_jitter(record: RunLog, tracked: set[int] | None = None) -> tuple[Jitter, Jitter]:
    """The jitter of the published positions of tracked frames and of the ground truth over
    the same frames (the truth's is NaN without one)."""
    stamps = frame_stamps(record)
    tracked = tracked_stamps(record) if tracked is None else tracked
    published = {s: p[:3, 3] for s, p in record.poses.items() if s in tracked}
    truth = {s: record.ground_truth[s][:3, 3] for s in published if s in record.ground_truth}
    return jitter(published, stamps), jitter(truth, stamps)


def _jitter_cells(record: RunLog, tracked: set[int]) -> tuple[float, float, float, float, float]:
    shake, truth = run_jitter(record, tracked)
    return (shake.rms_mm, shake.median_mm, shake.p95_mm, float(shake.over_visible),
            truth.rms_mm)


def device_cpu_ms(record: RunLog) -> float:
    """The device's mean CPU milliseconds a frame, over the frames that report it (NaN when
    none does: a device of a version before the field)."""
    spent = [float(f.cpu_ms) for s in record.summaries.values() for f in s.frames
             if f.cpu_ms > 0]
    return float(np.mean(spent)) if spent else math.nan


def dropped_frames(record: RunLog, slot_frames: int, skipped: int = 0) -> int:
    """Frames missing from every slot but the last, and from the last up to its newest frame
    the device summarised (:func:`missing_in_last_slot`; the run may end inside it), less the
    ``skipped`` frames the player never published (unreadable files: the data's fault, not
    the machine's). A skip in the last slot takes one off a drop elsewhere: the player counts
    its skips, it does not say in which slot they fell."""
    slots = sorted(record.summaries)
    missing = sum(max(0, slot_frames - len(record.summaries[s].frames)) for s in slots[:-1])
    return max(0, missing + missing_in_last_slot(record) - skipped)


def missing_in_last_slot(record: RunLog) -> int:
    """Frames the player published within the last slot before the device's newest summarised
    frame that the device has no summary of — counted by the player's ground truth, one pose a
    published frame (0 without it). A slot's length cannot count them: the run may end inside
    its last slot; but a frame published between two the device summarised reached the
    device's camera topic and was dropped there (a loaded machine)."""
    slots = sorted(record.summaries)
    if not slots or not record.ground_truth:
        return 0
    last = record.summaries[slots[-1]].frames
    if not last:
        return 0
    before = record.summaries[slots[-2]].frames if len(slots) > 1 else []
    start = max((time_key(f.stamp) for f in before), default=-1)
    end = max(time_key(f.stamp) for f in last)
    published = sum(1 for stamp in record.ground_truth if start < stamp <= end)
    return max(0, published - len(last))


def relocalised_stamps(record: RunLog) -> list[int]:
    """The stamps (ns) of the frames the device counted as tracked again after a
    relocalisation (and its probation)."""
    return [time_key(f.stamp) for s in record.summaries.values() for f in s.frames
            if f.tracked and f.relocalised]


#: how the edge names a slot its learned policy left to the fallback rule ("adapt (fallback)")
FALLBACK = " (fallback)"


def deciders(record: RunLog) -> str:
    """"name:slots" for each policy that decided a slot of the run, comma-separated, in the
    order they first decided."""
    counts: dict[str, int] = {}
    for slot in sorted(record.requests):
        name = str(record.requests[slot].policy)
        counts[name] = counts.get(name, 0) + 1
    return ", ".join(f"{name}:{n}" for name, n in counts.items())


def decided_policies(decided_by: str) -> list[str]:
    """The policies a :func:`deciders` cell names, in its order."""
    names = []
    for entry in decided_by.split(", "):
        name, _, slots = entry.rpartition(":")
        if name and slots.isdigit():
            names.append(name)
    return names


def print_table(reports: list[RunReport], echo: Callable[[str], None] = print) -> None:
    echo(RunReport.HEADER)
    for r in reports:
        echo(r.row())
    for r in reports:
        if (line := r.pieces_line(r.label)) is not None:
            echo(line)

