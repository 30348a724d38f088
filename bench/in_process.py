"""One slot of the live protocol with the device and edge cores in one process: the frames'
summaries to the edge, its plan, the uploads it asked for, the slot's end and the map update
back to the device — the nodes' work without DDS and without the uplink's delay, for the
benchmarks that drive whole walks through the cores (:class:`DeviceWalk`: a default device
and edge core over a sequence, frame by frame).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from device_tracker.device_core import DeviceTrackerCore
from device_tracker.messages import read_map_update
from device_tracker.parameters import PARAMETERS as DEVICE_PARAMETERS
from device_tracker.parameters import DeviceSettings
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, SlotOutcome
from edge_mapper.messages import map_update_message
from edge_mapper.parameters import PARAMETERS as EDGE_PARAMETERS
from edge_mapper.parameters import edge_config
from edge_mapper.slot_planner import FrameObservations
from twinslam.node_runtime.long_lived_objects import keep_survivors_out
from twinslam.node_runtime.math_threads import one_math_thread
from twinslam.node_runtime.parameters import ParamSpec
from twinslam.policies.registry import make_policy
from twinslam.sequence_player.playback import Playback, PlayedSequence, played_device_slot
from twinslam.sequences.frame import RgbdFrame
from twinslam.sequences.opening import AUTO, open_sequence
from twinslam.slam.back_end.foreign_keyframes import foreign_mask, source_id
from twinslam.slam.back_end.loop_closing import LoopQuery
from twinslam.slam.back_end.loop_detection import MIN_INLIERS as LOOP_MIN_INLIERS
from twinslam.slam.back_end.map_merging import (
    LENT_VIEW_DEG,
    LENT_VIEW_M,
    MERGE_MIN_INLIERS,
    lent_view,
)
from twinslam.slam.back_end.place_words import PlaceWords
from twinslam.slam.back_end.view_coverage import CoverageBounds
from twinslam.slam.keyframe import KeyFramePayload, is_track
from twinslam.slam.map_update import MapSnapshot
from twinslam.slam.viewing_directions import seen_from_afar
from twinslam.slot_protocol import default_device, table1
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS
from twinslam.uplink.channels import MarkovChannel, TraceChannel, parse_channel
from twinslam.uplink.families import uplink_family


class EdgeFrame(NamedTuple):
    """One frame of a served slot as the edge planned it."""

    frame_id: int
    covered: bool       #: left out of the upload candidates: the map covers its view
    uploaded: bool      #: the edge asked for it
    shared: int         #: its reported map points the planned-on map shares
    lost: bool          #: the edge's lost-frame rule counts it lost


@dataclass(frozen=True)
class ServedSlot:
    """What the edge made of a slot, and how long each of its steps took."""

    outcome: SlotOutcome
    plan_ms: float          #: the policy's decision with its observation
    integrate_ms: float     #: the requested keyframes added to the map
    finish_ms: float        #: eviction, bundle adjustment, checkpoint, uncertainty
    #: the map update, when the caller applies it itself (``hold``); None: applied already
    update: MapSnapshot | None = None
    #: the share of the slot's frames the edge's lost-frame rule counts lost (MapStats'
    #: lost_share; NaN: the map was empty)
    lost_share: float = math.nan
    #: the map the slot was planned on fell into pieces (u(G) = +inf): every frame of the
    #: slot counts lost by the edge's rule, whatever the device tracked
    in_pieces: bool = False
    #: the slot's frames as the edge planned them, capture order (empty: not recorded)
    frames: tuple[EdgeFrame, ...] = ()
    #: the device's own keyframes in the map the slot was planned on (the rest: other
    #: devices' copies)
    own_keyframes: int = 0


@dataclass(frozen=True)
class SlotHooks:
    """What an edge node does around one device's slot beside that device's core, for a bench
    that serves several devices as one node does (the maps' merging over their cores)."""

    #: each keyframe the edge accepted from the device, as the node hands it on
    keyframe: Callable[[KeyFramePayload], None]
    #: before the core's slot end: part of the slot's compute, timed with the slot end (the
    #: node's MapStats count it so)
    before_end: Callable[[int], None]
    #: after the slot end: work the node hands to a worker beside the slots, not timed
    after_end: Callable[[int], None]


def serve_slot(device: DeviceTrackerCore, edge: EdgeMapperCore, rate_mbps: float,
               rate_state: int, hold: bool = False, hooks: SlotHooks | None = None
               ) -> ServedSlot:
    """The device's finished slot through the edge, and the new map applied at the device
    at once. The summaries carry what the edge node reads from the wire: the observed points
    and tracks, the tracked flag and the pose (``mpc`` predicts from the poses; an untracked
    frame is never uploaded). ``hold``: the update is returned for the caller to apply later
    (as a live device gets it some frames into the next slot). ``hooks``: what the node does
    around the core's work besides (None: nothing)."""
    frames = device.take_slot()
    slot = frames[-1].slot
    summaries = [FrameObservations(f.frame_id, frozenset(f.map_point_ids.tolist()),
                                   frozenset(f.track_ids.tolist()), bool(f.tracked), f.pose,
                                   f.map_version)
                 for f in frames]
    own = sum(1 for k in edge.slice.keyframes if edge.device.owns(k))
    t0 = time.perf_counter()
    plan = edge.plan(slot, summaries, rate_mbps, rate_state)
    t1 = time.perf_counter()
    for frame_id in plan.action.upload:
        payload = device.upload(frame_id)
        if payload is None:
            raise RuntimeError(f"slot {slot}: the device no longer holds frame {frame_id}, "
                               "which the edge asked for in the same slot")
        report = edge.add_keyframe(payload)
        if hooks is not None and report is not None and not report.refused:
            hooks.keyframe(payload)
    t2 = time.perf_counter()
    if hooks is not None:
        hooks.before_end(slot)
    outcome = edge.finish_slot(slot)
    t3 = time.perf_counter()
    if hooks is not None:
        hooks.after_end(slot)
    update = map_update_message(edge.slice, slot, outcome.version, time.time(),
                                tracks=outcome.tracks, frame_correction=edge.frame_correction)
    snapshot = read_map_update(update)
    lost = plan.uncertainty.lost_share if plan.uncertainty is not None else math.nan
    pieces = plan.uncertainty is not None and math.isinf(plan.uncertainty.map_uncertainty)
    asked = set(plan.action.upload)
    planned = tuple(EdgeFrame(f.frame_id, f.frame_id in plan.covered, f.frame_id in asked, n, gone)
                    for f, n, gone in zip(summaries, plan.shared, plan.lost, strict=True))
    if not hold:
        device.apply_map_update(snapshot, slot)
    return ServedSlot(outcome, (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3,
                      snapshot if hold else None, lost, pieces, planned, own)


def run_as_the_edge_node() -> None:
    """Set this process up as the edge node sets up its own where that bears on the map's
    work (:func:`~twinslam.node_runtime.node_main.run_node`): the math libraries on one
    thread, and what survived a full garbage collection kept out of the next ones
    (:mod:`~twinslam.node_runtime.long_lived_objects`); OpenCV on one thread too, the
    devices' front ends sharing the process. The node's allocator setting, for camera frames
    arriving over DDS, is left out: no frame crosses DDS here. Without the collection
    setting, an in-process run of eight devices on the corridor paid 18 full collections of
    ~0.22 s each (4.0 s of 373, ``gc.callbacks``): stalls of the slots they fell in that the
    node does not have."""
    cv2.setNumThreads(1)
    one_math_thread()
    keep_survivors_out()


def seeded_spec(spec: str, seed: int) -> str:
    """A synthetic walk named by its frame count alone (``synthetic:600``) walked on ``seed``;
    a spec that names its seed, or a dataset's, as it is."""
    return f"{spec}:{seed}" if spec.startswith("synthetic") and spec.count(":") == 1 else spec


def repeatable_edge(**overrides: object) -> EdgeConfig:
    """The edge node's default configuration with ``overrides`` (its parameters by name),
    the loop closer working in the caller: a walk through the cores gives the same answer
    run after run, whatever the threads' timing."""
    params: dict[str, object] = {p.name: p.default for p in EDGE_PARAMETERS}
    params.update(overrides)
    config = edge_config(params)
    return dataclasses.replace(config, back_end=dataclasses.replace(config.back_end,
                                                                    loop_background=False))


class MapSearch(NamedTuple):
    """A frame's search of the map it held, split by who made each point: the device's own
    edge map (its own ids), another device's (a copy's points, tagged), or the device itself
    since its last map update (its new points, not on the edge yet) — in view of the
    predicted pose, searched for (the tracker's candidates), matched to a feature, and
    observed by the frame (its pose's inliers, and at a keyframe the old points it fused: the
    record's ``map_point_ids``). Found and observed count the edge's points only. Last, of
    the edge's points in view and of those searched, the ones the frame saw from more than
    :data:`AFAR_DEG` off the direction the map's keyframes saw them from (none in view where
    ``TrackingConfig.max_view_angle_deg`` left them out; none of the edge's where the device
    keeps no direction for them, ``DeviceTrackerCore.view_directions``)."""

    in_view_own: int
    in_view_others: int
    in_view_device: int
    searched_own: int
    searched_others: int
    searched_device: int
    found_own: int
    found_others: int
    observed_own: int
    observed_others: int
    afar_own: int
    afar_others: int
    searched_afar_own: int
    searched_afar_others: int


#: the turn from a point's viewing direction :class:`MapSearch` counts as seen from afar:
#: ORB-SLAM's local map search refuses a point past it
AFAR_DEG = 60.0


def by_maker(ids: np.ndarray) -> tuple[int, int, int]:
    """(the device's edge map's own, other devices', the device's new points) of a map's
    point ids."""
    ids = np.asarray(ids, dtype=np.uint64)
    new = is_track(ids)
    points = ids[~new].astype(np.int64)
    others = int(foreign_mask(points).sum())
    return len(points) - others, others, int(new.sum())


def map_search(device: DeviceTrackerCore, observed: np.ndarray, pose: np.ndarray
               ) -> MapSearch:
    """The device's last frame's :class:`MapSearch`; ``observed``: its record's map points,
    ``pose``: its camera-to-world."""
    search, points = device.tracking.last_search, device.tracking.map

    def afar(rows: np.ndarray) -> tuple[int, int]:
        if not device.view_directions:      # the edge's points carry no direction: none afar
            return 0, 0
        rows = rows[seen_from_afar(points.views[rows], points.positions[rows], pose[:3, 3],
                                   AFAR_DEG)]
        return by_maker(device.labels[rows])[:2]

    return MapSearch(*by_maker(device.labels[search.in_view]),
                     *by_maker(device.labels[search.searched]),
                     *by_maker(device.labels[search.found])[:2], *by_maker(observed)[:2],
                     *afar(search.in_view), *afar(search.searched))


#: (device, edge, d_k, rate state, hold the update) → what the edge made of the slot
Serving = Callable[[DeviceTrackerCore, EdgeMapperCore, float, int, bool], ServedSlot]


@dataclass
class DeviceWalk:
    """One device walking the sequence, with its edge core and uplink."""

    name: str
    frames: Iterator[RgbdFrame]
    device: DeviceTrackerCore
    edge: EdgeMapperCore
    channel: MarkovChannel | TraceChannel
    update_delay: int
    #: the map update waiting to reach the device: (update, its slot, the frame it left at)
    held: tuple[MapSnapshot, int, int] | None = None
    poses: dict[int, np.ndarray] = field(default_factory=dict)   #: frame → published pose
    truth: dict[int, np.ndarray] = field(default_factory=dict)
    map_version: dict[int, int] = field(default_factory=dict)  #: frame → map it tracked on
    slot: int = -1                     #: the device's last slot the edge served
    first_truth: np.ndarray | None = None    #: the true pose of its map frame (first frame)
    edge_ms: list[float] = field(default_factory=list)
    #: each served slot's share of frames the edge's lost-frame rule counted lost
    lost: list[float] = field(default_factory=list)
    #: the served slots planned on a map in pieces (``ServedSlot.in_pieces``)
    pieces: int = 0
    #: every frame as the device tracked it: (frame, tracked, features matched, pose
    #: inliers, map points among them, map version)
    frame_rows: list[tuple[int, int, int, int, int, int]] = field(default_factory=list)
    #: every frame's search of the map it held, by who made the points (frame's played
    #: position → :class:`MapSearch`)
    searches: dict[int, MapSearch] = field(default_factory=dict)
    #: every served frame as the edge planned it: (slot, frame's played position, covered,
    #: uploaded, map points shared, lost by the edge's rule, the device's own keyframes in
    #: the map)
    edge_rows: list[tuple[int, int, int, int, int, int, int]] = field(default_factory=list)
    #: the loops its edge closed: (slot, old keyframe, new keyframe, metres moved)
    loops: list[tuple[int, int, int, float]] = field(default_factory=list)
    uploads: int = 0                #: keyframes the edge integrated from this device
    #: the device's frame id (its keyframes' ids) → the frame's played position (the key of
    #: ``poses`` and ``truth``): the two differ once a walk skips frames (``bench.shared_map
    #: --interleave``)
    positions: dict[int, int] = field(default_factory=dict)
    #: how a finished slot is served (another bench times the edge's steps in finer detail)
    serve: Serving = serve_slot

    def step(self) -> list[int] | None:
        """Track the next frame (serving the slot it ends): the keyframes the edge integrated
        when a slot finished, [] otherwise; None when the walk is over."""
        frame = next(self.frames, None)
        if frame is None:
            return None
        result = self.device.track(frame.color, frame.depth, frame.stamp)
        record = result.record
        self.positions[record.frame_id] = frame.index
        # read before a held update replaces the map the frame searched
        self.searches[frame.index] = map_search(self.device, record.map_point_ids,
                                                record.pose)
        if self.held is not None and (result.slot_done or
                                      frame.index - self.held[2] >= self.update_delay):
            self.device.apply_map_update(self.held[0], self.held[1])
            self.held = None
        if frame.pose is not None:
            if self.first_truth is None:
                self.first_truth = frame.pose
            self.truth[frame.index] = frame.pose
            if record.tracked:
                self.poses[frame.index] = record.pose
                self.map_version[frame.index] = record.map_version
        self.frame_rows.append((frame.index, int(record.tracked), record.matches,
                                record.inliers, len(record.map_point_ids),
                                record.map_version))
        if not result.slot_done:
            return []
        state, rate = self.channel.step()
        served = self.serve(self.device, self.edge, rate, state, self.update_delay > 0)
        self.slot = served.outcome.slot
        self.edge_ms.append(served.plan_ms + served.integrate_ms + served.finish_ms)
        self.lost.append(served.lost_share)
        self.edge_rows.extend((served.outcome.slot, self.positions[f.frame_id], int(f.covered),
                               int(f.uploaded), f.shared, int(f.lost), served.own_keyframes)
                              for f in served.frames)
        self.pieces += served.in_pieces
        self.uploads += len(served.outcome.integrated)
        loop = served.outcome.loop
        if loop is not None and loop.old >= 0 and not loop.refused:
            self.loops.append((served.outcome.slot, loop.old, loop.new, loop.moved_m))
        if served.update is not None:
            self.held = (served.update, served.outcome.slot, frame.index)
        return [k for k in served.outcome.integrated if k in self.edge.map.keyframes]

    def map_lost_share(self) -> float:
        """Of the frames the device tracked on a map and those it did not track at all, the
        share it tracked on fewer of the map's points than it needs (``MIN_INLIERS``) or not
        at all: frames the map it held did not serve, by the device's own count — the edge's
        lost-frame rule judges the reported points against the edge's newer map instead."""
        held = [0 if not tracked else points for _, tracked, _, _, points, version
                in self.frame_rows if version > 0 or not tracked]
        return float(np.mean(np.array(held) < MIN_INLIERS)) if held else math.nan

    def query(self, keyframe: int) -> LoopQuery | None:
        """The integrated keyframe's features as the device uploaded them (None: no longer
        held)."""
        payload = self.device.upload(keyframe)
        return None if payload is None else LoopQuery.of(payload)

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        """Every keyframe of its edge map, archive and map, where the edge holds it now."""
        return self.edge.back_end.keyframe_poses()

    def own_keyframe_poses(self) -> dict[int, np.ndarray]:
        """Its own keyframes' poses (:meth:`keyframe_poses`, the copies of other devices'
        left out) by their frames' played positions, the keys of ``truth``."""
        owns = self.edge.device.owns
        return {self.positions.get(source_id(k), k): pose
                for k, pose in self.keyframe_poses().items() if owns(k)}


def _node_parameter(text: str, specs: Sequence[ParamSpec], names: Collection[str],
                    what: str) -> tuple[str, object]:
    """``NAME=VALUE`` as one of a node's parameters ``specs`` whose name is among ``names``,
    VALUE typed as its default is and within the spec's bounds, as the node would take it."""
    name, sep, value = text.partition("=")
    spec = next((p for p in specs if p.name == name), None)
    if not sep or spec is None or name not in names:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected NAME=VALUE with NAME {what} ({', '.join(sorted(names))})")
    kind = type(spec.default)
    if kind is bool:
        return name, value.lower() in ("1", "true", "yes", "on")
    try:
        typed = kind(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from exc
    if isinstance(typed, (int, float)) and (
            (spec.low is not None and typed < spec.low) or
            (spec.high is not None and typed > spec.high)):
        raise argparse.ArgumentTypeError(f"{text!r}: {name} lies within [{spec.low}, "
                                         f"{spec.high}]")
    return name, typed


def device_parameter(text: str) -> tuple[str, object]:
    """``NAME=VALUE`` as a device node parameter, VALUE typed as its default is."""
    return _node_parameter(text, DEVICE_PARAMETERS, [p.name for p in DEVICE_PARAMETERS],
                           "a device parameter")


class _ReadNames(dict[str, Any]):
    """A parameter mapping that notes which names are read."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        super().__init__(values)
        self.read: set[str] = set()

    def __getitem__(self, name: str) -> Any:
        self.read.add(name)
        return super().__getitem__(name)


def _core_parameters() -> frozenset[str]:
    """The edge node's parameters its core's configuration is made of (what
    :func:`~edge_mapper.parameters.edge_config` reads): the ones a bench of edge cores can
    honour; the node's others (its policy, topics, budget, …) no core reads."""
    values = _ReadNames({p.name: p.default for p in EDGE_PARAMETERS})
    edge_config(values)
    return frozenset(values.read)


#: the edge parameters ``--edge`` takes (:func:`_core_parameters`)
EDGE_CORE_PARAMETERS = _core_parameters()


def edge_parameter(text: str) -> tuple[str, object]:
    """``NAME=VALUE`` as an edge node parameter its core reads, VALUE typed as its default is
    and within its bounds."""
    return _node_parameter(text, EDGE_PARAMETERS, EDGE_CORE_PARAMETERS,
                           "an edge parameter the edge's core reads")


def parameters_text(params: Iterable[tuple[str, object]]) -> str:
    """Node parameters ``NAME=VALUE`` (a bench's ``--device``/``--edge`` pairs) as one CSV
    cell: ``name=value`` each, sorted by name, separated by spaces."""
    return " ".join(f"{k}={v}" for k, v in sorted(dict(params).items()))


def _add_node_option(parser: argparse.ArgumentParser, flag: str,
                     parse: Callable[[str], tuple[str, object]], help_text: str) -> None:
    """A repeatable ``NAME=VALUE`` option for one node's parameters (parsed by ``parse``)."""
    parser.add_argument(flag, action="append", default=[], metavar="NAME=VALUE", type=parse,
                        help=help_text)


def add_edge_option(parser: argparse.ArgumentParser) -> None:
    """``--edge NAME=VALUE`` (repeatable) on a bench's command line: the edge node's
    parameters that differ from its defaults, for every device's edge core; the bench passes
    ``dict(args.edge)`` to :func:`repeatable_edge` (its own options, named for one of them,
    win over it)."""
    _add_node_option(parser, "--edge", edge_parameter,
                     "an edge node parameter other than its default, as the node reads it, "
                     "for every device's edge core (repeat for more); e.g. restore_keyframes=6 "
                     "vmax=30. Only the parameters the core reads (not the node's policy, "
                     "topics or budget)")


def add_device_option(parser: argparse.ArgumentParser) -> None:
    """``--device NAME=VALUE`` (repeatable) on a bench's command line: the device node's
    parameters that differ from its defaults, for every device of the run; the bench reads
    them as ``dict(args.device)``."""
    _add_node_option(parser, "--device", device_parameter,
                     "a device node parameter other than its default, as the node reads it, "
                     "for every device of the run (repeat for more); e.g. map_source=edge "
                     "own_map_after_s=0: the paper's device, which tracks on the edge's map "
                     "alone")


def interleaved_device(device_params: Mapping[str, object], every: int) -> dict[str, object]:
    """The device parameters for a device that plays one frame in ``every`` (the player's
    ``every``): the default slot as the fleet launch plays it
    (:func:`~twinslam.sequence_player.playback.played_device_slot`), a slot as long in
    fewer frames.
    A rate or slot given in ``device_params`` stands. Raises :class:`ValueError` where the
    default slot's frames do not split ``every`` ways."""
    params = dict(device_params)
    if every == 1:
        return params
    if "slot_frames" not in params:
        try:
            params["slot_frames"], _ = played_device_slot({}, every)
        except ValueError as err:
            raise ValueError(f"{err}: give the device's slot_frames (--device "
                             "slot_frames=N)") from None
    params.setdefault("frame_rate_hz", table1.FRAME_RATE_HZ / every)
    return params


def add_place_options(parser: argparse.ArgumentParser) -> None:
    """The edge's merging, lending and covered-view settings on a bench of devices in one
    place (``bench.shared_map``, ``bench.place_walks``), named as the edge's parameters;
    :func:`check_place_options` refuses what the edge would."""
    parser.add_argument("--merge-inliers", type=int, default=MERGE_MIN_INLIERS, metavar="N",
                        help="the PnP inliers each of a merge's detections needs (the edge's "
                             f"merge_min_inliers; default %(default)s; a loop's "
                             f"{LOOP_MIN_INLIERS} at least)")
    parser.add_argument("--lend-eagerly", action="store_true",
                        help="lend each keyframe as soon as its device made it "
                             "(lend_in_view:=false), not once the borrowing device heads "
                             "where it sees it")
    parser.add_argument("--unseen-slots", type=int, default=0, metavar="N",
                        help="a copy neither held nor seen by its borrowing device for N "
                             "slots goes back to its lender (the edge's lent_unseen_slots; "
                             "default %(default)s: kept; not with --lend-eagerly)")
    parser.add_argument("--lent-view-m", type=float, default=LENT_VIEW_M, metavar="M",
                        help="a view lent once: another device's keyframe is not lent where a "
                             "copy the borrowing map holds stands within M metres of it (the "
                             "edge's lent_view_m; default %(default)s: every keyframe lent)")
    parser.add_argument("--lent-view-deg", type=float, default=LENT_VIEW_DEG, metavar="D",
                        help="and turned by at most D degrees (the edge's lent_view_deg; "
                             "default %(default)s)")
    parser.add_argument("--covered-m", type=float, metavar="M",
                        help="a lent keyframe this near a frame covers its view: the frame is "
                             "not uploaded (default: the edge's covered_m; 0: never)")
    parser.add_argument("--covered-deg", type=float, metavar="D",
                        help="and turned by at most this (default: the edge's covered_deg)")
    parser.add_argument("--covered-min-points", type=int, metavar="N",
                        help="a covered frame is left out only where N of its reported points "
                             "are the map's (default: the edge's covered_min_points, 50; 15 "
                             "is the device's tracking floor: any frame the map serves)")
    parser.add_argument("--covered-by-points", action=argparse.BooleanOptionalAction,
                        help="a frame that shares --covered-min-points of its reported points "
                             "with the keyframes another device lent is covered too, wherever "
                             "it stands (the edge's covered_by_points; default: the edge's)")
    parser.add_argument("--own-coverage-after", type=int, metavar="N",
                        help="a device's own keyframe of an earlier visit (restored, or "
                             "uploaded N slots before or more) covers a frame's view as a "
                             "lent one does (the edge's own_coverage_after_slots; default: "
                             "the edge's; 0: never)")
    parser.add_argument("--vocabulary-per-device", action="store_true",
                        help="each device's archive learns visual words of its own "
                             "(shared_vocabulary:=false), not one vocabulary for the process's "
                             "devices")


def lent_views(args: argparse.Namespace) -> CoverageBounds | None:
    """The bounds within which a copy a borrowing map holds declines another keyframe of its
    view (``--lent-view-m``, ``--lent-view-deg``), or None: every keyframe lent."""
    return lent_view(args.lent_view_m, args.lent_view_deg)


def share_vocabulary(cores: Iterable[EdgeMapperCore], per_device: bool) -> None:
    """The devices' archives searched under one vocabulary, as the edge node's are
    (``shared_vocabulary``, :class:`~edge_mapper.device_link.LinkSettings`' ``words``);
    ``per_device``: each under its own."""
    if per_device:
        return
    words = PlaceWords()
    for core in cores:
        core.archive.words.share(words)


def check_place_options(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Exit with the parser's error where :func:`add_place_options`' values are out of the
    edge's range."""
    if args.merge_inliers < LOOP_MIN_INLIERS:
        parser.error(f"--merge-inliers must be at least a loop's {LOOP_MIN_INLIERS}, got "
                     f"{args.merge_inliers}")
    if args.unseen_slots < 0:
        parser.error(f"--unseen-slots: 0 or more, got {args.unseen_slots}")
    if args.lent_view_m < 0 or args.lent_view_deg < 0:
        parser.error(f"--lent-view-m, --lent-view-deg: 0 or more, got {args.lent_view_m}, "
                     f"{args.lent_view_deg}")
    for name in ("covered_m", "covered_deg", "covered_min_points", "own_coverage_after"):
        value = getattr(args, name)
        if value is not None and value < 0:
            parser.error(f"--{name.replace('_', '-')}: 0 or more, got {value}")


def open_walk(name: str, spec: str, frames: int, order: str, seed: int, uplink: str,
              config: EdgeConfig, update_delay: int, folder: Path | None, start: int = 0,
              device_params: Mapping[str, object] | None = None, every: int = 1,
              phase: int = 0) -> DeviceWalk:
    """A default device and edge core over frames [``start``, ``frames``) of ``spec`` played
    in ``order``; ``device_params``: the device node's parameters that differ from its defaults
    (e.g. ``map_source``); ``every``, ``phase``: only the frames the player's ``every`` and
    ``phase`` play (:meth:`Playback.plays`), each keeping its position in the whole walk as
    its ``index`` (the bench's frame counts — ``update_delay``, the truth's keys — stay the
    walk's); the edge checkpoints its map into ``folder`` (None: no checkpoint)."""
    source = open_sequence(spec, start=start, end=frames, colour_intrinsics=AUTO)
    settings = DeviceSettings.from_parameters({p.name: p.default for p in DEVICE_PARAMETERS}
                                              | dict(device_params or {}))
    DeviceTrackerCore.warm_up(source.intrinsics)
    device = DeviceTrackerCore(source.intrinsics, settings.slot_frames, settings.tracking,
                               settings.keep_slots, settings.frame_rate_hz, settings.map_source,
                               settings.own_map_after)
    edge = EdgeMapperCore(make_policy(default_device.POLICY), source.intrinsics, config,
                          None if folder is None else folder / f"{name}.npz")
    family = uplink_family(uplink)
    channel = parse_channel(family.channel, family.rate_mbps or (5.0, 45.0), seed=seed,
                            slot_seconds=settings.slot_frames / settings.frame_rate_hz)
    walk = PlayedSequence(source, Playback(order))
    chosen = Playback(order, every=every, phase=phase)
    played = (f for f in walk if chosen.plays(walk.positions[f.index]))
    return DeviceWalk(name, played, device, edge, channel, update_delay)
