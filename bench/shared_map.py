"""Two devices in one place, one process: each with its own edge map, until the edge finds
the second device's keyframes in the first device's map, confirms it and moves the second
map into the first one's frame (:mod:`twinslam.slam.back_end.map_merging`).

    python -m bench.shared_map [SEQUENCE] [--frames 1000] [--first forward]
        [--second backward] [--second-after FRAMES] [--first-start FRAME]
        [--second-start FRAME] [--interleave] [--seed 0]
        [--uplink lte] [--vmax N] [--archive N] [--ba-window N] [--device NAME=VALUE]
        [--edge NAME=VALUE]
        [--share [--share-both]] [--covered-m M] [--covered-min-points N] [--no-merge] [--csv FILE]
        [--frames-csv FILE] [--keyframes-csv FILE]

Both devices play the same sequence, frame for frame in lockstep — by default the first
forward and the second backward: two users walking the place from its two ends, towards
each other; with ``--second forward --second-after 500`` the second comes to the place the
first is mapping 500 frames later (it walks on alone once the first is done); with
``--second forward --second-start 500`` both start together, the second from the walk's
frame 500 — two users in one place from different starts, as ``twinslam launch --devices N
--stride S`` plays them. Played so, the two devices capture the very same images: a merge
may pair a keyframe with the frame the other device uploaded, a match no two real devices
ever have (the 7-Scenes pair walked forward, one 500 frames after the other, merged so in
five seeds of six). With ``--interleave`` the first
plays the sequence's even frames and the second its odd ones, whichever way each walks (the
player's ``every`` and ``phase``), each at half the frame rate (its
steps twice as long), and no image is played by both; ``--second-after`` counts the first
device's frames played (``--second-after 250`` with it is 500 frames of the walk). Each device
and its edge core run as in ``bench.map_consistency`` (the default device and edge, the loop
closer in the caller, the map update ``--update-delay`` frames into the next slot), each on
an uplink of its own (seeds ``--seed`` and ``--seed`` + 1).
After each of the second device's slots its newly integrated keyframes are looked for in
everything the first device's edge map holds (archive and map) until a merge is confirmed.

It prints the merge (the slot, the keyframes, the inliers, and how far its alignment is
from the true one), and at the end, per device, the frames tracked and the ATE, then the
**cross-device revisit error**: for pairs of a frame of each device whose true poses lie
within 0.3 m and 20°, the translation error of their relative pose against the truth's
(:func:`~twinslam.live.tracking_quality.cross_device_revisit_error`) — content one user
anchored, as the other sees it — over the second device's frames published in the shared
frame; beside it the same frames carried by the *true* alignment of the two maps' frames
instead of the merge's (the two walks' drift apart: a merge found where the devices meet
aligns them there, which the true frames do not) and the two edge maps' final keyframes;
then the same error split in two (:func:`~twinslam.live.tracking_quality.rigid_part`): the
one rigid motion of the second device's frames that leaves it least — how far a better
merge alignment alone could bring the two maps together — and what is left after it, the
maps bending apart along the walk, which only one graph over both walks takes out.
Each device's uploads are counted: with ``--share`` a frame whose view a lent keyframe
covers is not asked for (the edge's ``covered_m``/``covered_deg``; ``--covered-m 0``: every
frame a candidate). ``--frames-csv`` and ``--keyframes-csv`` write every frame as
tracked and every keyframe each edge map ends with, and the loops each edge closed are
printed. Beside each device's uploads, two lost shares: the edge's lost-frame
rule (the share of a slot's frames whose reported points the edge's map — the one it is about
to send — holds fewer than 15 of) and the device's own count (the share of its frames, since
it first held a map, that it tracked on fewer than 15 points of the map it held, or not at
all). ``--csv`` appends one row a run.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.in_process import (
    DeviceWalk,
    add_device_option,
    add_edge_option,
    add_place_options,
    check_place_options,
    interleaved_device,
    lent_views,
    open_walk,
    parameters_text,
    repeatable_edge,
    run_as_the_edge_node,
    seeded_spec,
    share_vocabulary,
)
from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import (
    RevisitError,
    absolute_trajectory_error,
    cross_device_revisit_error,
    revisit_error,
    rigid_part,
)
from twinslam.reporting import append_csv_rows, write_csv
from twinslam.rotations import rotation_angle_deg
from twinslam.sequence_player.playback import ORDERS, phase_for
from twinslam.slam.back_end.foreign_keyframes import (
    foreign_tag,
    is_foreign,
    source_id,
    tag_of,
)
from twinslam.slam.back_end.map_merging import (
    Lender,
    MapMerge,
    MergeFinder,
    lend_from,
)
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.view_coverage import CoverageBounds

SEVEN = SEVEN_SCENES


def look_for_merge(finder: MergeFinder, place: DeviceWalk, joining: DeviceWalk,
                   keyframes: list[int], slot: int, index: KeptPlaceIndex | None = None
                   ) -> MapMerge | None:
    """The joining device's newly integrated ``keyframes`` looked for in everything the place
    device's edge map holds, under ``index`` where the looks keep one (as the edge's do):
    the merge, once confirmed."""
    other = place.edge.back_end.store.snapshot(slot, index)
    poses = joining.keyframe_poses()
    for kf in keyframes:
        query = joining.query(kf)
        merge = None if query is None else finder.offer(other, query, poses, joining.edge.k)
        if merge is not None:
            return merge
    return None


@dataclass
class LendingState:
    """One direction of lending from round to round: the lender as
    :func:`~twinslam.slam.back_end.map_merging.lend_from` keeps it (the edge's PlaceMerging
    keeps one per pair of devices), and what the rounds did."""

    lender: Lender
    eager: bool                                          #: every keyframe at once
    unseen_slots: int                                    #: copies unseen this long go back
    #: a copy held declines another keyframe of its view within these (None: never)
    views: CoverageBounds | None
    adopted: int = 0                                     #: adoptions, re-lent copies too
    returned: int = 0                                    #: copies gone back to the lender


def lend_keyframes(lender: DeviceWalk, borrower: DeviceWalk, state: LendingState,
                   slot: int) -> None:
    """The lender's own keyframes (archive and map; not those it adopted) the borrower's map
    has not adopted yet — unless ``state.eager``, only those the borrower's camera sees from
    where it heads — welded to its points and adopted into its archive at the borrower's slot
    (as the edge node does: its loops across devices count slots by it), after the lender's
    loops since the last lending moved the copies lent before them and the borrower's
    keyframes tied to them; with ``state.unseen_slots``, the copies its device has not held
    nor seen for that long go back (``slot``: the bench's, for the log)."""
    lending = lend_from(borrower.edge.back_end, [state.lender], max(borrower.slot, 0),
                        None if state.eager else borrower.edge.in_coming_view,
                        state.unseen_slots, state.views)[0]
    state.lender = dataclasses.replace(state.lender, followed=lending.followed)
    state.adopted += lending.adopted
    state.returned += lending.returned
    for move in lending.moves:
        if move.reached_own:
            print(f"slot {slot:4d}: the {borrower.name} map followed the {lender.name}'s loop: "
                  f"{move.copies} copies and {move.own} own keyframes moved, up to "
                  f"{move.own_moved_m * 100:.1f} cm, its graph {move.graph_ms:.0f} ms"
                  f"{'; ' + move.refused if move.refused else ''}", flush=True)


def alignment_error(merge: MapMerge, place: DeviceWalk, joining: DeviceWalk
                    ) -> tuple[float, float]:
    """(m, degrees) between the merge's alignment and the true one (the joining map's frame in
    the place map's, from the two devices' first true poses), at the joining device's newest
    pose: how far the merge put the joining device from where the place's map has it."""
    assert place.first_truth is not None and joining.first_truth is not None
    true = np.linalg.inv(place.first_truth) @ joining.first_truth
    head = joining.poses[max(joining.poses)]
    a, b = merge.alignment @ head, true @ head
    return (float(np.linalg.norm(a[:3, 3] - b[:3, 3])),
            rotation_angle_deg(a[:3, :3].T @ b[:3, :3]))


def pairs(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray],
          frames: list[int] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(pose, true pose) of ``frames`` (default: every posed frame) with a true pose."""
    keys = sorted(poses) if frames is None else frames
    return [(poses[k], truth[k]) for k in keys if k in poses and k in truth]


def self_error(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray],
               frames: list[int] | None = None) -> RevisitError:
    """One device against itself on the cross-device figure's pairs: every two distinct
    frames of ``frames`` (default: every posed frame) whose true poses lie within its bounds,
    however close in time. Two devices cannot be asked to agree better than each agrees with
    itself."""
    keys = sorted(poses) if frames is None else frames
    chosen = {k: poses[k] for k in keys if k in poses and k in truth}
    # frame indices stand for the stamps; a gap of 0: every two distinct frames
    return revisit_error(chosen, truth, chosen, gap_s=0.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEVEN),
                        help="the place both devices walk (default: the 7-Scenes frames)")
    parser.add_argument("--frames", type=int, default=1000, help="frames of it to play")
    parser.add_argument("--first", choices=ORDERS, default="forward",
                        help="the first device's order (its map is the place's frame)")
    parser.add_argument("--second", choices=ORDERS, default="backward",
                        help="the second device's order (its map joins the first's)")
    parser.add_argument("--seed", type=int, default=0,
                        help="the first uplink's seed (the second's: seed + 1) and a synthetic "
                             "walk's")
    parser.add_argument("--uplink", default="lte", help="uplink family (table1, lte, mmwave, "
                        "constrained)")
    parser.add_argument("--second-sequence", default="",
                        help="the second device's place, when it is another (two places on "
                             "one edge: a merge there is a false one, and the cross-device "
                             "figures compare two worlds' truths: not printed)")
    parser.add_argument("--second-after", type=int, default=0, metavar="FRAMES",
                        help="the second device starts once the first has played this many "
                             "frames and walks on alone after the first's walk ended (0: "
                             "both start together and stop with the first to end): with "
                             "--second forward, a user coming to a place another mapped")
    parser.add_argument("--first-start", type=int, default=0, metavar="FRAME",
                        help="the first device plays the sequence from this frame on")
    parser.add_argument("--interleave", action="store_true",
                        help="the two devices play alternate frames (the first the "
                             "sequence's even frames, the second its odd ones, whichever way "
                             "each walks), each at half the sequence's frame rate: "
                             "no image is played by both, as two real devices never capture "
                             "one, and a merge cannot pair a frame with itself")
    parser.add_argument("--second-start", type=int, default=0, metavar="FRAME",
                        help="the second device plays the sequence from this frame on "
                             "(forward or backward over frames [FRAME, --frames))")
    parser.add_argument("--vmax", type=int,
                        help="V_max, keyframes each edge map holds (default: the edge's)")
    parser.add_argument("--archive", type=int, metavar="N",
                        help="evicted keyframes each edge map keeps, its own and those lent "
                             "(the edge's archive_keyframes; default: the node's)")
    parser.add_argument("--ba-window", type=int, metavar="N",
                        help="the newest keyframes each edge map bundle-adjusts a slot "
                             "(the edge's ba_window; default: the node's, 0; the paper's "
                             "edge: 5)")
    add_device_option(parser)
    add_edge_option(parser)
    parser.add_argument("--update-delay", type=int, default=8,
                        help="frames of the next slot a device tracks before its map update "
                             "reaches it (the default device's D_req of 0.25 s)")
    parser.add_argument("--share", action="store_true",
                        help="after the merge, the second edge map adopts the first's "
                             "keyframes (welded to its points) into its archive after each "
                             "slot: restores bring them in where the second device heads")
    parser.add_argument("--share-both", action="store_true",
                        help="with --share: the first edge map adopts the second's keyframes "
                             "too")
    parser.add_argument("--join", action="store_true",
                        help="at the merge, the second device's map joins the first's: one "
                             "map of the place, each device's slice of it, its keyframes "
                             "restored into the other's where the camera heads, one bundle "
                             "adjustment and loop closer (the first's) — instead of --share's "
                             "copies; both edges write no checkpoint (a joined place does not "
                             "yet), so compare it with --share --no-checkpoints")
    parser.add_argument("--no-checkpoints", action="store_true",
                        help="the edges write no map checkpoint (as --join must)")
    parser.add_argument("--no-loops-across", action="store_true",
                        help="with --share: the second map's loops close among its own "
                             "keyframes only, never with the first device's lent keyframes "
                             "(the edge's loops_across_devices:=false)")
    add_place_options(parser)
    parser.add_argument("--no-merge", action="store_true",
                        help="never merge (the control: each device in its own frame)")
    parser.add_argument("--every", type=int, default=10, help="print every N slots")
    parser.add_argument("--csv", type=Path, help="append the run's figures here")
    parser.add_argument("--frames-csv", type=Path,
                        help="write every frame of both devices as tracked: features matched, "
                             "pose inliers, map points among them, map version")
    parser.add_argument("--keyframes-csv", type=Path,
                        help="write every keyframe each edge map holds at the end (archive "
                             "and map; its own or lent) with its position and the truth's in "
                             "the first device's frame")
    args = parser.parse_args()
    check_place_options(parser, args)
    if args.join and (args.share or args.no_merge):
        parser.error("--join is another way to share the place than --share, and needs a "
                     "merge (not --no-merge)")
    run_as_the_edge_node()
    spec, second_spec = (seeded_spec(s, args.seed) for s in
                         (args.sequence, args.second_sequence or args.sequence))
    overrides = {name: value for name, value in (("vmax", args.vmax),
                                                 ("archive_keyframes", args.archive),
                                                 ("ba_window", args.ba_window),
                                                 ("covered_m", args.covered_m),
                                                 ("covered_deg", args.covered_deg),
                                                 ("covered_min_points",
                                                  args.covered_min_points),
                                                 ("covered_by_points", args.covered_by_points),
                                                 ("own_coverage_after_slots",
                                                  args.own_coverage_after),
                                                 ("loops_across_devices",
                                                  False if args.no_loops_across else None))
                 if value is not None}
    config = repeatable_edge(**{**dict(args.edge), **overrides})
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        # interleaved, no image is played by both: the first device the sequence's even
        # frames, the second its odd ones, whichever way each walks (the player's every and
        # phase, counted from where each starts), each at half the frame rate (a slot still
        # a second)
        every = 2 if args.interleave else 1
        device_params = interleaved_device(dict(args.device), every)
        folder = None if args.join or args.no_checkpoints else Path(tmp)
        first = open_walk("first", spec, args.frames, args.first, args.seed, args.uplink,
                          config, args.update_delay, folder, start=args.first_start,
                          device_params=device_params, every=every,
                          phase=phase_for(0, args.first_start, every))
        second = open_walk("second", second_spec, args.frames, args.second, args.seed + 1,
                           args.uplink, config, args.update_delay, folder,
                           start=args.second_start, device_params=device_params, every=every,
                           phase=phase_for(1, args.second_start, every))
        share_vocabulary((first.edge, second.edge), args.vocabulary_per_device)
        finder = MergeFinder(min_inliers=args.merge_inliers)
        merge: MapMerge | None = None
        merged_version = -1            #: the second edge's first map version in the place's
        merge_row: dict[str, object] = {}
        look_ms: list[float] = []      #: each slot's search for the first map's place
        #: the first map's keyframes lent to the second, and the second's to the first
        lending, lending_back = (
            LendingState(Lender(walk.edge.back_end, source, set(), 0), args.lend_eagerly,
                         args.unseen_slots, lent_views(args))
            for walk, source in ((first, 0), (second, 1)))
        copies_held: dict[str, list[int]] = {"first": [], "second": []}
        slot = 0
        #: the looks' place index of the first map, kept from look to look as the edge's
        look_index = KeptPlaceIndex()
        first_on = True
        played = 0                     #: the first device's frames so far
        while True:
            got_a = first.step() if first_on else None
            played += got_a is not None
            first_on = got_a is not None
            got_b = second.step() if played >= args.second_after or not first_on else []
            if got_b is None or (got_a is None and args.second_after == 0):
                break
            got_a = got_a or []
            if not got_b and not got_a:
                continue
            slot += 1
            if merge is None and not args.no_merge and got_b:
                looked = time.perf_counter()
                merge = look_for_merge(finder, first, second, got_b, slot, look_index)
                look_ms.append((time.perf_counter() - looked) * 1e3)
                if merge is not None:
                    t_err, r_err = alignment_error(merge, first, second)
                    merged_version = second.edge.version + 1
                    if args.join:
                        second.edge.join_place(first.edge, foreign_tag(1), merge.alignment)
                        print(f"slot {slot:4d}: the second device's map joined the first's, "
                              f"{len(second.edge.ids.fused)} of its points fused into the "
                              "place's", flush=True)
                    else:
                        second.edge.align(merge.alignment)
                    merge_row = {"merge_slot": slot, "merge_frame": max(second.poses),
                                 "merge_inliers": merge.inliers,
                                 "alignment_error_m": t_err, "alignment_error_deg": r_err}
                    print(f"slot {slot:4d}: merged - the second device's keyframe "
                          f"{merge.joining} found the first's keyframe {merge.place} on "
                          f"{merge.inliers} inliers, confirmed ({finder.candidates} "
                          f"keyframes found it); alignment {t_err * 100:.1f} cm, "
                          f"{r_err:.2f}° from the true one", flush=True)
            if merge is not None and args.share and (got_a or got_b):
                lend_keyframes(first, second, lending, slot)
                # as the edge node: a map's loops may close with the keyframes it borrowed
                # (edge_mapper.place_merging)
                second.edge.back_end.loop_across = frozenset({foreign_tag(0)})
                if args.share_both:
                    lend_keyframes(second, first, lending_back, slot)
                    first.edge.back_end.loop_across = frozenset({foreign_tag(1)})
                for walk in (first, second):
                    copies_held[walk.name].append(sum(
                        1 for k in walk.edge.back_end.store.ids() if is_foreign(k)))
            if slot % args.every == 0 and not second.edge.serves_place:
                print(f"slot {slot:4d}: the place's map {len(first.edge.map.keyframes)} + "
                      f"archive {len(first.edge.archive)}, the first device's slice "
                      f"{len(first.edge.slice.keyframes)}, the second's "
                      f"{len(second.edge.slice.keyframes)}", flush=True)
            elif slot % args.every == 0:
                print(f"slot {slot:4d}: first map {len(first.edge.map.keyframes)} + archive "
                      f"{len(first.edge.archive)}, second map {len(second.edge.map.keyframes)} "
                      f"+ archive {len(second.edge.archive)}; {_merge_state(merge, finder)}",
                      flush=True)
        first.edge.close()
        second.edge.close()
        for walk in (first, second):
            for loop_slot, old_kf, new_kf, moved in walk.loops:
                on = f"the other device's keyframe {source_id(old_kf)}" \
                    if is_foreign(old_kf) else f"{old_kf}"
                print(f"the {walk.name} edge closed a loop in its slot {loop_slot}: keyframe "
                      f"{new_kf} on {on}, moving its map up to {moved * 100:.1f} cm")
        if args.frames_csv:
            write_frames(args.frames_csv, (first, second))
        if args.keyframes_csv:
            write_keyframes(args.keyframes_csv, (first, second))
        shared = [k for k, v in second.map_version.items() if v >= merged_version >= 0]
        # the second device's poses each in its own map's frame (the merge's alignment taken
        # out of those published after it) and each in the place's (put into those before)
        align = np.eye(4) if merge is None else merge.alignment
        after = set(shared)
        own = {k: np.linalg.inv(align) @ p if k in after else p
               for k, p in second.poses.items()}
        placed = {k: align @ p for k, p in own.items()}
        report: dict[str, object] = {"share": 0}
        if args.share:
            restored = sum(1 for k in second.edge.map.keyframes if is_foreign(k))
            back = sum(1 for k in first.edge.map.keyframes if is_foreign(k))
            report.update(adopted=lending.adopted, foreign_at_end=restored,
                          adopted_back=lending_back.adopted, foreign_at_end_first=back,
                          share=2 if args.share_both else 1,
                          lent_unseen_slots=args.unseen_slots, returned=lending.returned,
                          returned_back=lending_back.returned,
                          **{f"{name}_copies_mean": float(np.mean(held)) if held else 0.0
                             for name, held in copies_held.items()})
            if args.share_both:
                print(f"the first map adopted {lending_back.adopted} of the second map's "
                      f"keyframes, {lending_back.returned} went back; {back} of its "
                      f"{len(first.edge.map.keyframes)} at the end")
            print(f"the second map adopted {lending.adopted} of the first map's keyframes, "
                  f"{lending.returned} went back; {restored} of its "
                  f"{len(second.edge.map.keyframes)} keyframes at the end are the first "
                  "device's")
        report.update({"frames": args.frames, "seed": args.seed, "uplink": args.uplink,
                       "first_order": args.first, "second_order": args.second,
                       "second_after": args.second_after, "second_start": args.second_start,
                       "first_start": args.first_start,
                       "archive": config.back_end.archive_keyframes,
                       "ba_window": config.back_end.ba_window,
                       "device_params": parameters_text(args.device),
                       "edge_params": parameters_text(args.edge),
                       "covered_m": config.coverage.max_m,
                       "covered_deg": config.coverage.max_deg,
                       "covered_min_points": config.coverage.min_points,
                       "covered_by_points": int(config.coverage.by_points),
                       "own_coverage_after": config.own_coverage_after_slots,
                       "lent_view_m": args.lent_view_m, "lent_view_deg": args.lent_view_deg,
                       "declined": len(lending.lender.declined),
                       "declined_back": len(lending_back.lender.declined),
                       "no_merge": int(args.no_merge), "join": int(args.join),
                       "checkpoints": int(folder is not None),
                       "joined_points_fused": len(second.edge.ids.fused),
                       "loops_across_devices": int(config.back_end.loops_across_devices),
                       "merged": int(merge is not None),
                       "merge_min_inliers": args.merge_inliers,
                       "interleave": int(args.interleave),
                       **merge_row,
                       "look_ms_median": float(np.median(look_ms)) if look_ms else math.nan,
                       "look_ms_max": max(look_ms, default=math.nan)})
        if look_ms:
            print(f"looking for the first map's place: {len(look_ms)} slots, median "
                  f"{np.median(look_ms):.0f} ms, longest {max(look_ms):.0f} ms a slot")
        for walk, poses in ((first, first.poses), (second, placed)):
            ate = absolute_trajectory_error(poses, walk.truth)
            report[f"{walk.name}_tracked"] = len(poses)
            report[f"{walk.name}_ate_m"] = ate
            report[f"{walk.name}_edge_ms"] = float(np.median(walk.edge_ms))
            report[f"{walk.name}_uploads"] = walk.uploads
            # as a live run's table: the slots after the first (it plans on an empty map)
            scored = [v for v in walk.lost[1:] if not math.isnan(v)]
            report[f"{walk.name}_lost_share"] = float(np.mean(scored)) if scored else math.nan
            report[f"{walk.name}_map_lost_share"] = walk.map_lost_share()
            report[f"{walk.name}_loops"] = len(walk.loops)
            # the loops it closed with another device's keyframe (a copy: a tagged id)
            # (a joined device's loops are its place's first device's)
            report[f"{walk.name}_loops_across"] = sum(
                1 for edge in walk.edge.back_end.loop_edges
                if is_foreign(edge.old)) if walk.edge.serves_place else 0
            own_archived = sum(1 for kf in walk.edge.archive if walk.edge.device.owns(kf.id))
            report[f"{walk.name}_archive_own"] = own_archived
            report[f"{walk.name}_archive_copies"] = len(walk.edge.archive) - own_archived
            print(f"{walk.name} device: {len(poses)} of {len(walk.truth)} frames tracked, "
                  f"ATE {ate * 100:.1f} cm (in the place's frame), {walk.uploads} keyframes "
                  f"uploaded, the edge's lost share "
                  f"{report[f'{walk.name}_lost_share']:.1%}, frames its map did not serve "
                  f"{report[f'{walk.name}_map_lost_share']:.1%}, edge median "
                  f"{np.median(walk.edge_ms):.0f} ms a slot")
        first_pairs = pairs(first.poses, first.truth)
        second_pairs = pairs(second.poses, second.truth, shared if merge else None)
        cross = cross_device_revisit_error(first_pairs, second_pairs)
        rigid = rigid_part(first_pairs, second_pairs)
        assert first.first_truth is not None and second.first_truth is not None
        true = np.linalg.inv(first.first_truth) @ second.first_truth
        floor = cross_device_revisit_error(
            first_pairs,
            pairs({k: true @ p for k, p in own.items()}, second.truth, shared or None))
        kf_cross = cross_device_revisit_error(
            pairs(first.own_keyframe_poses(), first.truth),
            pairs(second.own_keyframe_poses(), second.truth)) if merge else RevisitError()
        # where along the second device's walk the two disagree: its frames in the shared
        # frame STRETCH at a time in its play order (a crossing both walked at once shows)
        ordered = sorted(shared) if merge else sorted(second.poses)
        by_stretch = [cross_device_revisit_error(pairs(first.poses, first.truth),
                                                 pairs(second.poses, second.truth,
                                                       ordered[i:i + STRETCH]))
                      for i in range(0, len(ordered), STRETCH)]
        # the second device's last LAST played frames, in the shared frame: past the merge
        # in every condition measured, so two conditions whose merges come at different
        # slots are compared on the same frames (the whole figure counts only frames after
        # the merge: a later merge leaves out the crossing just after it)
        last_frames = [k for k in list(second.truth)[-LAST:] if k in after or not merge]
        last = cross_device_revisit_error(pairs(first.poses, first.truth),
                                          pairs(second.poses, second.truth, last_frames))
        # each device against itself: the first over its walk, the second over its frames
        # in the shared frame (a pair across its merge would count the merge's motion)
        selves = (self_error(first.poses, first.truth),
                  self_error(second.poses, second.truth, shared if merge else None))
    report.update(shared_frames=len(shared), cross_rms_m=cross.rms_m,
                  cross_median_m=cross.median_m, cross_p95_m=cross.p95_m,
                  cross_pairs=cross.pairs, true_alignment_rms_m=floor.rms_m,
                  cross_rigid_left_rms_m=rigid.left.rms_m, cross_rigid_moved_m=rigid.moved_m,
                  cross_rigid_turned_deg=rigid.turned_deg,
                  keyframes_cross_rms_m=kf_cross.rms_m, first_self_rms_m=selves[0].rms_m,
                  second_self_rms_m=selves[1].rms_m,
                  cross_by_stretch_cm=";".join(f"{e.rms_m * 100:.1f}" for e in by_stretch),
                  cross_last_rms_m=last.rms_m, cross_last_pairs=last.pairs,
                  cross_last_frames=sum(1 for k in last_frames if k in second.poses))
    if second_spec != spec:
        print(f"two places: {'MERGED (a false merge)' if merge else 'not merged'} "
              f"({time.perf_counter() - started:.0f} s)")
        report.update(cross_rms_m=math.nan, cross_median_m=math.nan, cross_p95_m=math.nan,
                      cross_pairs=0, true_alignment_rms_m=math.nan,
                      keyframes_cross_rms_m=math.nan, cross_by_stretch_cm="",
                      cross_rigid_left_rms_m=math.nan, cross_rigid_moved_m=math.nan,
                      cross_rigid_turned_deg=math.nan,
                      cross_last_rms_m=math.nan, cross_last_pairs=0, cross_last_frames=0)
    else:
        print(f"cross-device revisit error, the second device's {len(shared)} frames in the "
              f"shared frame: RMS {_cm(cross.rms_m)}, median {_cm(cross.median_m)}, p95 "
              f"{_cm(cross.p95_m)} ({cross.pairs} pairs); the same frames with the true "
              f"alignment instead of the merge's {_cm(floor.rms_m)}; the two edge maps' "
              f"final keyframes {_cm(kf_cross.rms_m)}; each device against itself on "
              f"such pairs {_cm(selves[0].rms_m)} and {_cm(selves[1].rms_m)} "
              f"({time.perf_counter() - started:.0f} s)")
        print(f"cross-device revisit error left once the second device's frames move by the "
              f"rigid motion that fits them best ({_cm(rigid.moved_m)}, "
              f"{rigid.turned_deg:.2f}°): RMS "
              f"{_cm(rigid.left.rms_m)}: the rest is one rigid offset "
              "between the two maps (what a better merge alignment could take out)")
        if ordered:
            print(f"cross-device revisit error by the second device's {STRETCH} frames at a "
                  f"time in the shared frame, in its order from its frame {ordered[0]}: "
                  + ", ".join(_cm(e.rms_m) for e in by_stretch))
        print(f"cross-device revisit error over the second device's last {LAST} frames: RMS "
              f"{_cm(last.rms_m)} ({last.pairs} pairs, {report['cross_last_frames']} of its "
              "frames in the shared frame)")
    if args.csv:
        append_csv_rows(args.csv, CSV_FIELDS, [report])


CSV_FIELDS = ("frames", "seed", "uplink", "first_order", "second_order", "second_after",
              "no_merge", "covered_m", "covered_deg", "covered_min_points", "own_coverage_after",
              "covered_by_points", "merged", "merge_slot", "merge_frame",
              "merge_inliers", "alignment_error_m", "alignment_error_deg", "look_ms_median",
              "look_ms_max", "first_tracked",
              "first_ate_m", "first_edge_ms", "second_tracked", "second_ate_m",
              "second_edge_ms", "shared_frames", "cross_rms_m", "cross_median_m",
              "cross_p95_m", "cross_pairs", "true_alignment_rms_m", "keyframes_cross_rms_m",
              "share", "first_uploads", "second_uploads", "adopted", "foreign_at_end",
              "adopted_back", "foreign_at_end_first", "first_lost_share", "second_lost_share",
              "first_map_lost_share", "second_map_lost_share", "second_start",
              "first_start", "archive", "first_loops", "second_loops", "first_archive_own",
              "second_archive_own", "loops_across_devices", "first_loops_across",
              "second_loops_across", "first_self_rms_m", "second_self_rms_m",
              "cross_by_stretch_cm", "merge_min_inliers", "cross_last_rms_m",
              "cross_last_pairs", "cross_last_frames", "ba_window",
              "device_params", "lent_unseen_slots", "returned", "returned_back",
              "lent_view_m", "lent_view_deg", "declined", "declined_back",
              "first_archive_copies", "second_archive_copies", "first_copies_mean",
              "second_copies_mean", "cross_rigid_left_rms_m",
              "cross_rigid_moved_m", "cross_rigid_turned_deg", "interleave", "edge_params")
#: the second device's frames a stretch of the cross-device error by stretch counts
STRETCH = 100
#: the second device's last frames played, the set ``cross_last_rms_m`` scores
LAST = 300


def write_frames(path: Path, walks: tuple[DeviceWalk, ...]) -> None:
    """Every frame of ``walks`` as its device tracked it, a row each."""
    write_csv(path, ("device", "frame", "tracked", "matches", "inliers", "map_points",
                     "map_version"),
              [(walk.name, *row) for walk in walks for row in walk.frame_rows])


def write_keyframes(path: Path, walks: tuple[DeviceWalk, ...]) -> None:
    """Every keyframe each walk's edge holds now, with the truth of its frame in the first
    walk's frame — which a map is in only once it merged. A copy of another walk's keyframe
    (walk k's tagged ``foreign_tag(k)``) takes its truth from that walk: the walks may play
    the sequence in other orders, or other frames of it."""
    first = walks[0].first_truth
    assert first is not None
    place = np.linalg.inv(first)
    by_tag = {foreign_tag(source): walk for source, walk in enumerate(walks)}
    rows = []
    for walk in walks:
        for kf, pose in sorted(walk.keyframe_poses().items()):
            owner = by_tag.get(tag_of(kf)) if is_foreign(kf) else walk
            frame = source_id(kf)
            position = owner.positions.get(frame) if owner is not None else None
            truth = owner.truth.get(position) if owner is not None and position is not None \
                else None
            true_xyz = (place @ truth)[:3, 3] if truth is not None else (math.nan,) * 3
            rows.append((walk.name, kf, int(is_foreign(kf)), frame,
                         -1 if position is None else position, *pose[:3, 3], *true_xyz))
    write_csv(path, ("device", "keyframe", "lent", "frame", "played", "x", "y", "z", "true_x",
                     "true_y", "true_z"), rows)


def _merge_state(merge: MapMerge | None, finder: MergeFinder) -> str:
    """Merged, or what the last keyframe looked for found."""
    if merge is not None:
        return "merged"
    found = finder.last
    if found is None:
        return "not merged"
    return f"not merged (last look: {f'found {found.old}' if found.found else found.reason})"


def _cm(metres: float) -> str:
    return "–" if math.isnan(metres) else f"{metres * 100:.1f} cm"


if __name__ == "__main__":
    main()
