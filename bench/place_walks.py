"""Many devices walking one place one after another, in one process, their maps merged and
lent as the edge node merges them: the node's own
:class:`~edge_mapper.place_merging.PlaceMerging` over every device's edge core.

    python -m bench.place_walks [SEQUENCE[,SEQUENCE…]] [--devices 4] [--frames 2700]
        [--after 300] [--order forward[,backward…]] [--seed 0] [--uplink lte]
        [--unseen-slots N] [--lend-eagerly] [--merge-inliers N] [--look-backoff N]
        [--no-merge | --join]
        [--covered-m M] [--covered-deg D] [--covered-min-points N]
        [--interleave N] [--own-walks] [--edge NAME=VALUE …] [--every 300] [--csv FILE]
        [--frames-csv FILE] [--baseline COMMIT [--rounds 1]]

Device k (k = 0, 1, …) starts the walk ``k × --after`` frames after the first, on an uplink
of its own (seed ``--seed`` + k): users joining a place others walk at different times — on
the corridor (the default), each comes to ground the devices ahead of it mapped and leaves
it behind, the case a borrower's copies that go back (``--unseen-slots``) are for. With
orders separated by commas device k plays order k mod N: ``--order forward,backward --after
0`` walks the corridor from its two ends at once, each device alone until they meet — the
case the looks' backoff (``--look-backoff``) is for: a device whose looks found nothing looks
less often, and its merge may wait for its next look. Each
device and its edge core run as in ``bench.shared_map`` (the default device and edge, the
loop closer in the caller, the map update ``--update-delay`` frames into the next slot). The
merging runs in the caller too (its looks are the node's worker's there), around each
device's slot end as the node's device link calls it: each accepted keyframe handed on, the
merges and the lending before the core's slot end (timed with it, as the node's MapStats
count them), the look after it. A device is served from its first slot, in the order the
devices start.

``SEQUENCE`` may name several places, separated by commas (``../shared/data/7scenes-1000,
synthetic-corridor:2700``): device k walks place k mod P, and the devices of different places
share one edge process as an edge serving users in several buildings does. Each device whose
map joined no other looks for its place in the other places' maps after every slot, for as
long as none is found: the looks' time (``look_ms_median``) is outside the devices' slot
medians, as the node's looks worker's is; a device whose map joins a device of another place
is a **false merge**, counted and named. With ``--join`` a merge makes one map of the place
(the edge's ``merge_join``) instead of lending each map the others' keyframes as copies.
Only devices of one place are paired for the cross-device figure.

It prints, per device, the frames tracked, its ATE over the frames it published in its
place's frame, the keyframes it uploaded, the edge's lost share, the edge's median ms a
slot, the other devices' keyframes its map held (mean over its slots, at the end) and how
many copies it adopted (a copy that went back and was lent again counts twice); then the
**cross-device revisit error** over every two devices of one place (their frames in the
place's frame, pooled as RMS over the pairs of frames), and each run's figures appended to
``--csv``; ``--frames-csv`` writes every frame the edge served, with its slot, whether the map
covered it, whether it was uploaded, the map points it shared and whether the edge counted it
lost and how many of its own keyframes the map held, beside whether the device tracked it,
on how many points of the map it held, and how many of that map's points — its own edge map's,
other devices' copies' and its own new points apart — were in view, searched for, found and
observed (where a walk's lost frames fall, and why).
Devices replaying one sequence see the same frames: a pair is two devices' estimates of one
view, and their relative pose's truth is the identity — and a merge or a copy's weld may
pair an image with itself, which no two real cameras offer. With
``--interleave N`` device k plays only the sequence's frames numbered k mod N, each device at
1/N of the frame rate with 1/N of a slot's frames (a slot lasts as long): with N at least the
devices of a place, no image is played by two of them. On a synthetic place ``--own-walks``
gives device k the walk of seed + k instead: its own sway, height and gaze through the same
world, at the full frame rate (each device's map alone is then in its own first camera's
frame, and the control ``--no-merge`` has no cross-device figure).

With ``--baseline COMMIT`` the same run is made in a worktree of that commit and in this
tree, alternating for ``--rounds`` rounds (bench/baseline.py): the edge's ms a device-slot
side by side, paired by round, and whether the two trees walked the same walk (uploads,
copies, loops, ATE and the cross-device error equal: a change that only speeds the edge up
leaves them so, the runs being deterministic). ``--csv`` then gets every run's row, with its
tree and round.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.baseline import add_baseline_options, alternately, run_in_tree
from bench.in_process import (
    DeviceWalk,
    MapSearch,
    SlotHooks,
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
    serve_slot,
    share_vocabulary,
)
from edge_mapper.edge_core import EdgeMapperCore
from edge_mapper.place_merging import PlaceMerging
from twinslam.cli.console import HelpFormatter
from twinslam.live.tracking_quality import (
    RevisitError,
    absolute_trajectory_error,
    cross_device_revisit_error,
)
from twinslam.reporting import append_csv_rows, write_csv
from twinslam.sequence_player.playback import ORDERS, phase_for
from twinslam.sequences.opening import focal_lengths, is_synthetic, with_focal

#: the CSV's columns: the run's settings, then its figures (per-device lists joined by ";")
COLUMNS = ("sequence", "frames", "devices", "after", "order", "seed", "uplink", "no_merge",
           "covered_m", "covered_deg", "covered_min_points", "covered_by_points",
           "own_coverage_after", "lend_in_view",
           "lent_unseen_slots", "lent_view_m", "lent_view_deg",
           "merge_min_inliers", "merge_look_backoff_slots",
           "merged", "edge_ms_median", "edge_ms_mean", "edge_ms_merged_median", "copies_mean",
           "copies_end", "adopted", "uploads", "lost_share", "map_lost_share", "tracked_share",
           "ate_m_mean", "cross_rms_m", "cross_pairs", "cross_worst_pair_rms_m", "loops",
           "look_ms_median", "seconds", "device_edge_ms", "device_copies_mean", "device_uploads",
           "device_merge_slot", "device_ate_m", "places", "false_merges", "declined",
           "interleave", "own_walks", "pieces_slots", "device_pieces_slots", "edge_params",
           "focals", "join")
#: the figures two trees' runs share when they walked one walk (the timings aside)
SAME_WALK = ("merged", "copies_mean", "copies_end", "adopted", "uploads", "lost_share",
             "tracked_share", "ate_m_mean", "cross_rms_m", "loops", "device_uploads",
             "device_merge_slot", "device_ate_m")


class PlaceWalk:
    """One device of the run: its walk, when it starts, and what the merging did to it."""

    def __init__(self, walk: DeviceWalk, start: int, place: int = 0) -> None:
        self.walk = walk
        self.start = start                    #: the run's frame it starts at
        self.place = place                    #: which of the run's places it walks
        self.done = False
        #: its first map version in its place's frame (-1: never merged; 0: a root)
        self.in_place = -1
        self.merge_slot = -1
        self.merge_index = -1                 #: its served slots before the merge
        self.adopted = 0
        self.copies: list[int] = []           #: other devices' keyframes held, a slot each

    @property
    def name(self) -> str:
        return self.walk.name

    def placed_frames(self) -> list[int]:
        """Its frames published in its place's frame: those tracked on a map version since
        its last move (a root's: all of them)."""
        if self.in_place < 0:
            return []
        return [k for k, v in self.walk.map_version.items() if v >= self.in_place]


def _hooks(device: PlaceWalk, merging: PlaceMerging) -> SlotHooks:
    """The node's device link's calls around ``device``'s slot end, recording its merges."""
    name, core = device.name, device.walk.edge

    def before_end(slot: int) -> None:
        merged, adopted, _ = merging.before_slot_end(name, slot)
        device.adopted += adopted
        if merged is not None:
            device.in_place = core.version + 1       # the slot end's update: the new frame
            device.merge_slot = slot
            device.merge_index = len(device.walk.edge_ms)
            print(f"{name} slot {slot:4d}: its map moved into {merged.place}'s frame "
                  f"({merged.merge.inliers} inliers"
                  f"{', with ' + merged.via + chr(39) + 's place' if merged.via else ''})",
                  flush=True)

    def after_end(slot: int) -> None:
        merging.look(name, slot)

    return SlotHooks(lambda payload: merging.keyframe(name, payload), before_end, after_end)


#: the columns of ``--frames-csv``
FRAME_COLUMNS = ("device", "slot", "frame", "covered", "uploaded", "shared", "lost",
                 "own_keyframes", "tracked", "device_map_points", "map_version",
                 "true_x", "true_y", "true_z", *(f"device_{name}" for name in MapSearch._fields))


def write_frames(path: Path, devices: list[PlaceWalk]) -> None:
    """Every frame the edge served, a row each (:data:`FRAME_COLUMNS`): where in a walk the
    edge's lost frames fall, and what the slots before them uploaded. Beside the edge's view
    of a frame, the device's: whether it tracked it, on how many map points of the map it
    held, and that map's version — a frame the edge counts lost may have been tracked on the
    map the device held, whose points the edge's newer map no longer has. ``frame`` is the
    frame's played position in the walk (``--interleave`` plays every Nth); the true position
    is in the device's own walk's frame (NaN without ground truth). Last, the device's search
    of the map it held (:class:`~bench.in_process.MapSearch`): the points in view, searched
    for, found and observed — its own edge map's, other devices' copies' and its own new
    points apart."""
    rows = []
    for device in devices:
        walk = device.walk
        tracked = {row[0]: row for row in walk.frame_rows}
        for slot, position, covered, uploaded, shared, lost, own in walk.edge_rows:
            _, was_tracked, _, _, map_points, version = tracked[position]
            truth = walk.truth.get(position)
            where = truth[:3, 3].tolist() if truth is not None else [math.nan] * 3
            rows.append((device.name, slot, position, covered, uploaded, shared, lost, own,
                         was_tracked, map_points, version, *where, *walk.searches[position]))
    write_csv(path, FRAME_COLUMNS, rows)


def false_merges(devices: list[PlaceWalk], roots: dict[str, str]) -> list[str]:
    """The devices whose map is in the frame of a device of another place (``roots``:
    device → its place's root, "" where maps never merge)."""
    place = {d.name: d.place for d in devices}
    return [d.name for d in devices
            if roots[d.name] and place.get(roots[d.name], d.place) != d.place]


def pooled(errors: list[RevisitError]) -> RevisitError:
    """Several pairs of devices' errors as one RMS over all their pairs of frames."""
    n = sum(e.pairs for e in errors)
    if n == 0:
        return RevisitError()
    return RevisitError(rms_m=math.sqrt(sum(e.rms_m ** 2 * e.pairs for e in errors if e.pairs)
                                        / n), pairs=n)


def _orders(text: str) -> tuple[str, ...]:
    """``--order``'s value: one order, or orders separated by commas, each one of ORDERS."""
    orders = tuple(o.strip() for o in text.split(","))
    bad = [o for o in orders if o not in ORDERS]
    if bad:
        raise argparse.ArgumentTypeError(f"not an order: {', '.join(map(repr, bad))} "
                                         f"(orders: {', '.join(ORDERS)})")
    return orders


def _focals(text: str) -> tuple[float, ...]:
    """``--focals``' value (:func:`~twinslam.sequences.opening.focal_lengths`)."""
    try:
        return focal_lengths(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default="synthetic-corridor:2700",
                        help="the place every device walks (default: the corridor walked out "
                             "and back twice), or places separated by commas: device k walks "
                             "place k mod P")
    parser.add_argument("--devices", type=int, default=4, help="devices walking it")
    parser.add_argument("--frames", type=int, default=2700, help="frames of it each plays")
    parser.add_argument("--after", type=int, default=300, metavar="FRAMES",
                        help="each device starts this many frames of the walk after the "
                             "one before (with --interleave N, after N times fewer frames "
                             "played)")
    parser.add_argument("--interleave", type=int, default=1, metavar="N",
                        help="device k plays only the sequence's frames numbered k mod N (the "
                             "player's every and phase), at 1/N of its frame rate, a slot "
                             "still as long: with N at least the devices of a place, no image "
                             "is played by two of them, as no two real cameras capture one")
    parser.add_argument("--own-walks", action="store_true",
                        help="device k walks the synthetic place on seed + k: a walk of its "
                             "own through the same world (its sway, height and gaze), as "
                             "several people walk one corridor — no image is played by two "
                             "devices; synthetic places only (a dataset is one recorded walk: "
                             "--interleave there)")
    parser.add_argument("--focals", type=_focals, default=(), metavar="PX[,PX…]",
                        help="each device's camera focal length in pixels, device k the k-th "
                             "mod their count (synthetic places only; default the world's "
                             "525): devices of one place with cameras of their own")
    parser.add_argument("--order", type=_orders, default=("forward",),
                        help=f"the order every device plays the frames in ({', '.join(ORDERS)}), "
                             "or orders separated by commas: device k plays order k mod N")
    parser.add_argument("--look-backoff", type=int, default=1, metavar="N",
                        help="after each look that found no candidate place a device waits "
                             "twice as many slots for its next, up to N (the edge's "
                             "merge_look_backoff_slots; default 1: a look after every slot)")
    parser.add_argument("--seed", type=int, default=0,
                        help="the first uplink's seed (device k's: seed + k) and a synthetic "
                             "walk's")
    parser.add_argument("--uplink", default="lte", help="uplink family (table1, lte, mmwave, "
                        "constrained)")
    add_device_option(parser)
    parser.add_argument("--update-delay", type=int, default=8,
                        help="frames of the next slot a device tracks before its map update "
                             "reaches it (the default device's D_req of 0.25 s)")
    add_place_options(parser)
    parser.add_argument("--no-merge", action="store_true",
                        help="never merge (the control: each device alone with its own map; "
                             "the devices play one walk from its first frame, so their maps' "
                             "frames are one by construction and the cross-device figure "
                             "still compares them)")
    parser.add_argument("--join", action="store_true",
                        help="a merge makes one map of the place (the edge's merge_join): "
                             "a device's map joins the place's, whose bundle adjustment and "
                             "loops run once; its uploads are every device's keyframes at once; "
                             "no edge writes a checkpoint (a joined place has none yet)")
    parser.add_argument("--every", type=int, default=300,
                        help="print the devices' maps every N frames of the run")
    add_edge_option(parser)
    parser.add_argument("--csv", type=Path, help="append the run's figures here")
    parser.add_argument("--frames-csv", type=Path,
                        help="write every served frame of every device here, a row each: its "
                             "slot, whether the map covered its view, whether the edge asked "
                             "for it, the map points it shared with the map the slot was "
                             "planned on, whether the edge counted it lost, how many of the "
                             "device's own keyframes that map held; whether the device tracked "
                             "it, on how many points of the map it held and that map's version; "
                             "where the camera truly stood; and the device's search of the map "
                             "it held: points in view, searched, found and observed — its own "
                             "edge map's, other devices' and its own new points apart")
    add_baseline_options(parser, 1, "rounds per tree, the whole run once a round")
    args = parser.parse_args()
    if args.devices < 2:
        parser.error(f"--devices: two or more walk one place, not {args.devices}")
    if args.after < 0:
        parser.error(f"--after: 0 or more, got {args.after}")
    check_place_options(parser, args)
    if args.rounds < 1:
        parser.error(f"--rounds: 1 or more, got {args.rounds}")
    if args.interleave < 1:
        parser.error(f"--interleave: 1 (every frame) or more, got {args.interleave}")
    try:
        device_params = interleaved_device(dict(args.device), args.interleave)
    except ValueError as err:
        parser.error(f"--interleave {args.interleave}: {err}")
    if args.own_walks and not all(is_synthetic(p) for p in args.sequence.split(",")):
        parser.error("--own-walks: a walk of each device's own needs a synthetic place "
                     f"(synthetic[:frames], synthetic-corridor[:frames]), not {args.sequence}")
    if args.focals and not all(is_synthetic(p) for p in args.sequence.split(",")):
        parser.error("--focals: a camera of each device's own needs a synthetic place, not "
                     f"{args.sequence}")
    if args.join and args.no_merge:
        parser.error("--join is how maps merge; --no-merge never merges them")
    if args.look_backoff < 1:
        parser.error(f"--look-backoff: 1 slot or more, got {args.look_backoff}")
    if args.baseline:
        _beside(args, sys.argv[1:])
        return
    run_as_the_edge_node()
    places = args.sequence.split(",")
    # the bench's own options win over --edge where both name a parameter
    config = repeatable_edge(**{**dict(args.edge), **{
        name: value for name, value in (("covered_m", args.covered_m),
                                        ("covered_deg", args.covered_deg),
                                        ("covered_min_points", args.covered_min_points),
                                        ("covered_by_points", args.covered_by_points),
                                        ("own_coverage_after_slots", args.own_coverage_after))
        if value is not None}})
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        devices = [PlaceWalk(open_walk(f"ar{k + 1}",
                                       with_focal(seeded_spec(places[k % len(places)],
                                                              args.seed + k if args.own_walks
                                                              else args.seed),
                                                  args.focals[k % len(args.focals)]
                                                  if args.focals else None), args.frames,
                                       args.order[k % len(args.order)], args.seed + k,
                                       args.uplink, config,
                                       args.update_delay, None if args.join else Path(tmp),
                                       device_params=device_params, every=args.interleave,
                                       phase=phase_for(k, 0, args.interleave)),
                             k * args.after // args.interleave, k % len(places))
                   for k in range(args.devices)]
        for device in devices:          # the frames' points seen from afar (MapSearch)
            device.walk.device.view_directions = True
        share_vocabulary((d.walk.edge for d in devices), args.vocabulary_per_device)
        served: dict[str, EdgeMapperCore] = {}
        merging = PlaceMerging(lambda: served, background=False,
                               min_inliers=args.merge_inliers,
                               lend_in_view=not args.lend_eagerly,
                               unseen_slots=args.unseen_slots,
                               lent_views=lent_views(args),
                               look_backoff_slots=args.look_backoff, join=args.join)
        for device in devices:
            if not args.no_merge:
                device.walk.serve = functools.partial(serve_slot,
                                                      hooks=_hooks(device, merging))
        # the first device's frame is its place's; alone, each device's own is (one walk)
        for device in devices if args.no_merge else devices[:len(places)]:
            device.in_place = 0
        tick = 0
        while not all(d.done for d in devices):
            for device in devices:
                if device.done or tick < device.start:
                    continue
                if device.name not in served and not args.no_merge:
                    served[device.name] = device.walk.edge
                    merging.serve(device.name)
                slots = len(device.walk.edge_ms)
                if device.walk.step() is None:
                    device.done = True
                elif len(device.walk.edge_ms) > slots:
                    # the other devices' keyframes: copies, or the joined place's
                    owns = device.walk.edge.device.owns
                    device.copies.append(sum(1 for k in device.walk.edge.back_end.store.ids()
                                             if not owns(k)))
            tick += 1
            if tick % args.every == 0:
                print(f"frame {tick:5d}: " + ", ".join(
                    f"{d.name} {len(d.walk.edge.map.keyframes)}+{len(d.walk.edge.archive)} kf"
                    f" ({d.copies[-1] if d.copies else 0} others')"
                    for d in devices if tick > d.start), flush=True)
        merging.close()
        for device in devices:
            device.walk.edge.close()
        report = _report(devices, merging, args)
        if args.frames_csv:
            write_frames(args.frames_csv, devices)
            print(f"wrote {args.frames_csv}")
    report["covered_m"], report["covered_deg"] = config.coverage.max_m, config.coverage.max_deg
    report["covered_min_points"] = config.coverage.min_points
    report["covered_by_points"] = int(config.coverage.by_points)
    report["lent_view_m"], report["lent_view_deg"] = args.lent_view_m, args.lent_view_deg
    report["own_coverage_after"] = config.own_coverage_after_slots
    report["edge_params"] = parameters_text(args.edge)
    report["seconds"] = time.perf_counter() - started
    print(f"{report['seconds']:.0f} s", flush=True)
    if args.csv:
        append_csv_rows(args.csv, COLUMNS, [report])
        print(f"appended to {args.csv}")


def _beside(args: argparse.Namespace, argv: list[str]) -> None:
    """The run (``argv`` without the side-by-side options) in the baseline commit's tree and
    this one, alternating; the edge's ms a device-slot of each, paired by round."""
    forwarded = _run_options(argv)

    def measure(r: int, label: str, root: Path) -> dict[str, str]:
        print(f"round {r + 1} {label}: the run in {root} …", flush=True)
        row = dict(run_in_tree(root, _DRIVER, *forwarded), tree=label, round=str(r + 1))
        print(f"round {r + 1} {label}: the edge {float(row['edge_ms_mean']):.1f} ms a "
              f"device-slot on the mean, {float(row['edge_ms_median']):.1f} median, "
              f"{float(row['edge_ms_merged_median']):.1f} after the merges (median); "
              f"{float(row['seconds']):.0f} s", flush=True)
        return row

    runs = alternately(args.baseline, args.rounds, measure)
    before, after = runs["baseline"], runs["current"]
    for figure in ("edge_ms_mean", "edge_ms_median", "edge_ms_merged_median"):
        change = [float(a[figure]) - float(b[figure]) for a, b in zip(after, before,
                                                                       strict=True)]
        print(f"{figure}: {args.baseline} {_listed(before, figure)}, this tree "
              f"{_listed(after, figure)}; this tree − {args.baseline} "
              + ", ".join(f"{c:+.1f}" for c in change) + " ms")
    differ = sorted({f for a, b in zip(after, before, strict=True) for f in SAME_WALK
                     if a[f] != b[f]})
    print("the same walk in both trees" if not differ else
          "NOT the same walk: " + ", ".join(differ) + " differ")
    if args.csv:
        append_csv_rows(args.csv, (*COLUMNS, "tree", "round"), [*before, *after])
        print(f"appended to {args.csv}")


#: one run in a tree (:func:`~bench.baseline.run_in_tree`: the forwarded options, then the
#: tree): its CSV row as JSON on the last line
_DRIVER = """
import csv, json, runpy, sys, tempfile
from pathlib import Path
with tempfile.TemporaryDirectory() as tmp:
    table = Path(tmp) / "run.csv"
    sys.argv = ["bench.place_walks", *sys.argv[1:-1], "--csv", str(table)]
    runpy.run_module("bench.place_walks", run_name="__main__")
    with table.open(newline="", encoding="utf-8") as fh:
        print(json.dumps(next(csv.DictReader(fh))))
"""


def _run_options(argv: list[str]) -> list[str]:
    """``argv`` without ``--baseline``, ``--rounds``, ``--csv`` and ``--frames-csv`` (each with
    its value)."""
    kept: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg in ("--baseline", "--rounds", "--csv", "--frames-csv"):
            skip = True
        elif not arg.startswith(("--baseline=", "--rounds=", "--csv=", "--frames-csv=")):
            kept.append(arg)
    return kept


def _listed(rows: list[dict[str, str]], figure: str) -> str:
    return " / ".join(f"{float(r[figure]):.1f}" for r in rows)


def _report(devices: list[PlaceWalk], merging: PlaceMerging, args: argparse.Namespace
            ) -> dict[str, object]:
    """Each device's figures printed, and the run's row."""
    for d in devices:
        walk, placed = d.walk, set(d.placed_frames())
        ate = absolute_trajectory_error({k: p for k, p in walk.poses.items() if k in placed},
                                        walk.truth)
        scored = [v for v in walk.lost[1:] if not math.isnan(v)]
        print(f"{d.name}: {len(walk.poses)} of {len(walk.truth)} frames tracked, "
              f"{len(placed)} in its place's frame (ATE {ate * 100:.1f} cm), "
              f"{walk.uploads} uploaded, the edge's lost share "
              f"{np.mean(scored) if scored else math.nan:.1%}, edge median "
              f"{np.median(walk.edge_ms):.0f} ms a slot, others' keyframes held "
              f"{np.mean(d.copies) if d.copies else 0:.1f} on the mean, "
              f"{d.copies[-1] if d.copies else 0} at the end, {d.adopted} adopted, the map "
              f"in pieces in {walk.pieces} slots")
    # alone, every device's map is in the walk's first camera's frame (one walk, one start);
    # on walks of their own each alone is in its own first camera's: no pair to compare
    roots = {d.name: (d.name if args.own_walks else "") if args.no_merge
             else merging.root(d.name) for d in devices}
    errors = [cross_device_revisit_error(
        [(a.walk.poses[k], a.walk.truth[k]) for k in a.placed_frames() if k in a.walk.truth],
        [(b.walk.poses[k], b.walk.truth[k]) for k in b.placed_frames() if k in b.walk.truth])
        for i, a in enumerate(devices) for b in devices[i + 1:]
        if a.place == b.place and roots[a.name] == roots[b.name] and a.in_place >= 0
        and b.in_place >= 0]
    false = false_merges(devices, roots)
    if false:
        print(f"FALSE MERGES: {', '.join(false)} joined a map of another place")
    cross = pooled(errors)
    worst = max((e.rms_m for e in errors if e.pairs), default=math.nan)
    print(f"cross-device revisit error, {len(errors)} pairs of devices in one place: RMS "
          f"{cross.rms_m * 100:.2f} cm over {cross.pairs} pairs of frames (the worst pair of "
          f"devices {worst * 100:.2f} cm)")
    every_ms = [ms for d in devices for ms in d.walk.edge_ms]
    merged_ms = [ms for d in devices if d.merge_index >= 0
                 for ms in d.walk.edge_ms[d.merge_index:]]
    copies = [c for d in devices for c in d.copies]
    lost = [v for d in devices for v in d.walk.lost[1:] if not math.isnan(v)]
    off = [d.walk.map_lost_share() for d in devices]      # by each device's own count
    ates = [absolute_trajectory_error({k: d.walk.poses[k] for k in d.placed_frames()
                                       if k in d.walk.poses}, d.walk.truth)
            for d in devices if d.in_place >= 0]
    return {"sequence": args.sequence, "frames": args.frames, "devices": args.devices,
            "after": args.after, "order": ",".join(args.order), "seed": args.seed,
            "interleave": args.interleave, "own_walks": int(args.own_walks),
            "focals": ";".join(f"{f:g}" for f in args.focals),
            "uplink": args.uplink, "no_merge": int(args.no_merge), "join": int(args.join),
            "lend_in_view": int(not args.lend_eagerly),
            "lent_unseen_slots": args.unseen_slots, "merge_min_inliers": args.merge_inliers,
            "merge_look_backoff_slots": args.look_backoff,
            "merged": sum(1 for d in devices if d.merge_slot >= 0),
            # the place's keyframes the maps declined at the end (lent_view_m)
            "declined": sum(merging.declined(d.name) for d in devices),
            "edge_ms_median": float(np.median(every_ms)),
            "edge_ms_mean": float(np.mean(every_ms)),
            "edge_ms_merged_median": float(np.median(merged_ms)) if merged_ms else math.nan,
            "copies_mean": float(np.mean(copies)) if copies else 0.0,
            "copies_end": sum(d.copies[-1] for d in devices if d.copies),
            "adopted": sum(d.adopted for d in devices),
            "uploads": sum(d.walk.uploads for d in devices),
            "lost_share": float(np.mean(lost)) if lost else math.nan,
            "map_lost_share": float(np.nanmean(off)) if not all(map(math.isnan, off))
            else math.nan,
            "tracked_share": sum(len(d.walk.poses) for d in devices)
            / max(sum(len(d.walk.truth) for d in devices), 1),
            "ate_m_mean": float(np.nanmean(ates)) if ates else math.nan,
            "cross_rms_m": cross.rms_m, "cross_pairs": cross.pairs,
            "cross_worst_pair_rms_m": worst,
            "loops": sum(len(d.walk.loops) for d in devices),
            "look_ms_median": float(np.median(merging.look_ms)) if merging.look_ms
            else math.nan,
            "device_edge_ms": ";".join(f"{np.median(d.walk.edge_ms):.1f}" for d in devices),
            "device_copies_mean": ";".join(f"{np.mean(d.copies) if d.copies else 0:.1f}"
                                           for d in devices),
            "device_uploads": ";".join(str(d.walk.uploads) for d in devices),
            "device_merge_slot": ";".join(str(d.merge_slot) for d in devices),
            "device_ate_m": ";".join(f"{a:.4f}" for a in ates),
            "places": args.sequence.count(",") + 1, "false_merges": len(false),
            "pieces_slots": sum(d.walk.pieces for d in devices),
            "device_pieces_slots": ";".join(str(d.walk.pieces) for d in devices)}


if __name__ == "__main__":
    main()
