"""``twinslam launch --devices N``: one edge serving N devices — a player and a
device per namespace (``/ar1`` … ``/arN``), each on its own walk and uplink seed, one
``edge_mapper`` with ``devices:=[ar1, …]`` and, with ``vmax_total``, one keyframe budget split
by an allocator; a monitor per namespace and one report per device, their mean and Jain's
index of the devices' tracked shares.

With ``--edges K`` the devices are split into K runs of neighbours (``ar1 … arM`` on the first
edge, and so on: neighbours play the same place where the devices' walks are laid out as
places), each served by an ``edge_mapper`` process of its own — ``edge_mapper``,
``edge_mapper_2`` … (each reads the parameter file's ``edge_mapper`` section) — with its
devices' share of ``vmax_total``; the edges meet over DDS like any other nodes, so the same
command runs them on network-namespace hosts ``edge``, ``edge2`` … with ``--hosts``.

On network-namespace hosts (``--hosts``) each device and its camera run on a host of their
own, named as the device, the edge on ``edge`` (the monitor beside it), each device's uplink
its own cable (``--tc`` shapes each at its d_k).

Walks: on the synthetic room each device plays its own seed's walk (``synthetic:F:i``); on a
dataset folder device i starts ``stride`` frames after device i − 1 (wrapping round), so the
devices see different places at a time.
"""

from __future__ import annotations

import itertools
import math
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
from twinslam_msgs.msg import MapStats

from msg_schemas.headers import time_key
from twinslam.allocation.allocators import check_fleet, jain_index
from twinslam.hosts.forked import NodeProcess
from twinslam.hosts.loopback import ProcessDomain
from twinslam.live.launcher import (
    LaunchConfig,
    Launcher,
    namespaced_params,
    preloaded_nodes,
    renamed_params,
)
from twinslam.live.monitor import PipelineMonitor
from twinslam.live.report import RunReport, report
from twinslam.live.run_log import RunLog
from twinslam.live.tracking_quality import (
    REVISIT_ANGLE_DEG,
    REVISIT_RADIUS_M,
    RevisitError,
    cross_device_revisit_error_by_frame,
)
from twinslam.node_runtime.middleware_teardown import ended_as_asked
from twinslam.node_runtime.session import RosSession
from twinslam.sequence_player.playback import ORDERS, phase_for, played_device_slot
from twinslam.sequences.opening import is_synthetic, synthetic_walk

#: a paced fleet's cameras keep one recording clock (the player's ``pace_group``): each device's
#: camera waits while any device is behind, so the walks meet when their recordings have them
#: meet; one fleet a domain, as its namespaces are
PACE_GROUP = "fleet"

#: what :func:`edge_blocks` splits: device names, place numbers
_Item = TypeVar("_Item")


@dataclass(frozen=True)
class FleetConfig:
    devices: int = 3
    vmax_total: int = 0              #: 0: each device has the parameter file's vmax
    allocator: str = "equal"
    min_keyframes: int = 5
    stride: int = 0                  #: frames between devices' starts on a dataset (0: even)
    seed: int = 0                    #: device i's channel (and synthetic walk): 100 seed + i
    #: each device's order of its frames (``forward``, ``backward``, …); empty: the scenario's
    orders: tuple[str, ...] = ()
    #: the edge merges a device's map into the frame of a device before it (``merge_maps``)
    merge_maps: bool = False
    #: edge processes the devices are split among, neighbours together (:meth:`blocks`)
    edges: int = 1
    #: seconds each device's camera starts after the fleet's (its player's ``start_delay_s``);
    #: empty: every device at once
    delays: tuple[float, ...] = ()
    #: the sequences (places) the devices walk, the devices split among them in runs of
    #: neighbours (:meth:`place_of`); empty: every device walks the launch's one sequence
    places: tuple[str, ...] = ()
    #: every device of a synthetic place walks one walk (seed 100 seed), each from where its
    #: order starts it: two devices from a corridor's two ends look the same way where they
    #: meet, as two users walking one route would
    one_walk: bool = False
    #: each camera plays one frame in ``every``, device ``index`` the sequence's frames
    #: numbered ``index mod every`` (the player's ``every`` and ``phase``), its device told the
    #: rate and slot in frames divided alike: two devices replaying one sequence, whichever
    #: ways, then never show one image, as no two real cameras would (1: every frame)
    every: int = 1
    #: with :attr:`merge_maps`, a merge makes the two maps one map of the place
    #: (``merge_join``) instead of lending each the other's keyframes
    join_maps: bool = False

    def phase(self, index: int, start: int = 0) -> int:
        """Device ``index``'s player's ``phase`` where its walk starts at the sequence's frame
        ``start`` (the player counts frames from there): its frames are the sequence's
        numbered ``index mod every``."""
        return phase_for(index, start, self.every)

    def device_seed(self, index: int) -> int:
        return 100 * self.seed + index

    def walk_seed(self, index: int) -> int:
        """The synthetic walk device ``index`` plays: its own (its channel's seed) or, with
        :attr:`one_walk`, the fleet's one."""
        return 100 * self.seed if self.one_walk else self.device_seed(index)

    def names(self) -> list[str]:
        return [f"ar{i + 1}" for i in range(self.devices)]

    def edge_names(self) -> list[str]:
        """The edges' node names: ``edge_mapper`` (the single edge's name), ``edge_mapper_2`` …"""
        return ["edge_mapper" if e == 0 else f"edge_mapper_{e + 1}" for e in range(self.edges)]

    def edge_hosts(self) -> list[str]:
        """The edges' hosts (``--hosts``): :func:`edge_hosts`."""
        return edge_hosts(self.edges)

    def place_of(self, index: int) -> int:
        """Which of :attr:`places` device ``index`` walks (0 with one place or none)."""
        if len(self.places) < 2:
            return 0
        runs = edge_blocks(list(range(self.devices)), len(self.places))
        return next(p for p, run in enumerate(runs) if index in run)

    def blocks(self) -> list[list[str]]:
        """Each edge's devices: runs of neighbours (:func:`edge_blocks`); with several places,
        each edge serves whole places — maps merge within one edge process, so a place's
        devices share one — the places split among the edges as evenly as they go."""
        names = self.names()
        if len(self.places) < 2:
            return edge_blocks(names, self.edges)
        places = edge_blocks(list(range(len(self.places))), self.edges)
        return [[d for i, d in enumerate(names) if self.place_of(i) in served]
                for served in places]

    def edge_shares(self) -> list[int]:
        """Each edge's part of ``vmax_total`` (its devices' share, the remainder one each to
        the first; 0: no shared budget). A total that covers every device's minimum covers
        each edge's devices' too."""
        if not self.vmax_total:
            return [0] * self.edges
        shares = [self.vmax_total * len(b) // self.devices for b in self.blocks()]
        for e in range(self.vmax_total - sum(shares)):          # the remainder, one each
            shares[e] += 1
        return shares

    def check(self) -> None:
        """ValueError naming a setting that cannot run."""
        check_fleet(self.devices, self.allocator, self.vmax_total, self.min_keyframes)
        if not 1 <= self.edges <= self.devices:
            raise ValueError(f"{self.edges} edges for {self.devices} devices: from one edge "
                             "to one a device")
        if self.orders and len(self.orders) != self.devices:
            raise ValueError(f"{len(self.orders)} orders for {self.devices} devices: give one "
                             "a device")
        if bad := [o for o in self.orders if o not in ORDERS]:
            raise ValueError(f"order {bad[0]!r}: must be one of {', '.join(ORDERS)}")
        if self.delays and len(self.delays) != self.devices:
            raise ValueError(f"{len(self.delays)} delays for {self.devices} devices: give one "
                             "a device")
        if bad_delays := [d for d in self.delays if not 0 <= d <= 86_400]:
            raise ValueError(f"delay {bad_delays[0]:g} s: from 0 to a day")
        if self.join_maps and not self.merge_maps:
            raise ValueError("joining maps is a way to merge them: it needs merge_maps")
        if not 1 <= self.every <= 1000:
            raise ValueError(f"every {self.every}: one frame in 1 to 1000")
        if len(self.places) > self.devices:
            raise ValueError(f"{len(self.places)} places for {self.devices} devices: at least "
                             "a device a place")
        if len(self.places) > 1 and self.edges > len(self.places):
            raise ValueError(f"{self.edges} edges for {len(self.places)} places: each edge "
                             "serves whole places (a place's maps merge within one edge "
                             f"process), at most {len(self.places)}")


def shared_images(fleet: FleetConfig, starts: Sequence[tuple[str, int]], frames: int,
                  lengths: Mapping[str, int | None]) -> list[tuple[str, str]]:
    """The pairs of devices whose cameras both show some image: the same sequence (a
    synthetic place's walks are a device's own unless :attr:`FleetConfig.one_walk`), frame
    windows [start, start + ``frames``) that overlap (``frames`` ≤ 0: to the end;
    ``lengths``: each sequence's frames, None where unknown) and, at ``every`` > 1, the same
    frame numbers modulo it — whichever orders they walk in. A merge between two such
    devices may pair an image with itself, which no two real cameras capture."""
    names = fleet.names()

    def window(index: int) -> range:
        sequence, start = starts[index]
        length = lengths.get(sequence)
        end = start + frames if frames > 0 else (length if length is not None else start + 1)
        return range(start, end if length is None else min(end, length))

    pairs = []
    for a, b in itertools.combinations(range(len(starts)), 2):
        if starts[a][0] != starts[b][0] or a % fleet.every != b % fleet.every:
            continue
        wa, wb = window(a), window(b)
        if max(wa.start, wb.start) < min(wa.stop, wb.stop):
            pairs.append((names[a], names[b]))
    return pairs


def edge_hosts(edges: int) -> list[str]:
    """The hosts of ``edges`` edge processes (``--hosts``): ``edge`` (a single edge's),
    ``edge2`` …, in :func:`edge_blocks`' order."""
    return ["edge" if e == 0 else f"edge{e + 1}" for e in range(edges)]


def edge_blocks(names: Sequence[_Item], edges: int) -> list[list[_Item]]:
    """``names`` split into ``edges`` runs of neighbours, as even as they go (their lengths
    differ by one at most; none empty): devices among edges, places among edges, devices
    among places."""
    edges = max(1, min(edges, len(names)))
    cuts = [round(i * len(names) / edges) for i in range(edges + 1)]
    return [list(names[a:b]) for a, b in itertools.pairwise(cuts)]


@dataclass
class FleetReport:
    """Each device's report, in device order, and what they add up to."""

    allocator: str
    devices: list[str]
    reports: list[RunReport]
    budgets: list[float]              #: each device's mean keyframe budget over its slots
    frames: list[int]                 #: frames each device's slots held
    #: per pair of devices (a, b): where b sees a's content, over their frames tracked on maps
    #: in one frame (:func:`cross_device_errors`)
    cross_device: dict[tuple[str, str], RevisitError] = field(default_factory=dict)
    #: pairs of devices of two places tracked on maps in one frame (a false merge)
    merged_across_places: list[tuple[str, str]] = field(default_factory=list)
    #: pairs of devices of one place ever tracked on maps in one frame (:func:`merged_in_place`)
    merged: list[tuple[str, str]] = field(default_factory=list)
    #: :attr:`cross_device` over the last :data:`LATE_SHARE` of each device's frames
    cross_device_late: dict[tuple[str, str], RevisitError] = field(default_factory=dict)
    #: each device whose map joined another device's frame: the slot and that frame
    #: (:func:`joined_at`)
    joined: dict[str, tuple[int, str]] = field(default_factory=dict)

    def tracked_shares(self) -> list[float]:
        """Each device's share of its frames it tracked."""
        return [1.0 - r.untracked_frames / n if n else math.nan
                for r, n in zip(self.reports, self.frames, strict=True)]

    @property
    def jain_tracked(self) -> float:
        """Jain's index of the devices' tracked shares (1: all alike)."""
        return jain_index(self.tracked_shares())


def device_sequence(sequence: str, index: int, devices: int, frames: int, start: int,
                    stride: int, length: int | None, walk_seed: int | None = None
                    ) -> tuple[str, int]:
    """(sequence, first frame) device ``index`` of ``devices`` plays: its own walk of the
    synthetic room (seed ``walk_seed``, default ``index``), or the dataset (``length``
    frames) from ``start + index × stride``, wrapping round (a stride of 0 spreads the
    devices evenly over it)."""
    if is_synthetic(sequence):
        return synthetic_walk(sequence, index if walk_seed is None else walk_seed,
                              max(frames, 1) + start), start
    if not length:
        return sequence, start
    step = stride or max(1, length // max(1, devices))
    return sequence, (start + index * step) % length


class FleetLauncher(Launcher):
    """``fleet.edges`` edges (one by default), ``fleet.devices`` devices, on ``domain``."""

    def __init__(self, domain: ProcessDomain, config: LaunchConfig, fleet: FleetConfig,
                 starts: Sequence[tuple[str, int]],
                 echo: Callable[[str], None] | None = print) -> None:
        super().__init__(domain, config, echo)
        fleet.check()
        self.fleet, self.starts = fleet, list(starts)
        self.records: dict[str, PipelineMonitor] = {}
        try:
            self._played_slot()
        except ValueError as err:
            raise ValueError(f"every {fleet.every}: {err} (the device's slot_frames must be "
                             "a multiple of it)") from None

    def _played_slot(self) -> tuple[int, float]:
        """A device's slot frames and nominal frame rate × ``rate``, as its camera plays one
        frame in ``every`` (:func:`played_device_slot`)."""
        return played_device_slot(self._device_given(), self.fleet.every, self.config.rate)

    def _device_slot_params(self) -> list[str]:
        """The launcher's, and where the camera plays one frame in ``every``, a slot as long
        in fewer frames: the played slot's frames and its rate (× the run's rate) in their
        stead, each told once."""
        if self.fleet.every == 1:
            return super()._device_slot_params()
        slot_frames, rate = self._played_slot()
        return [f"frame_rate_hz:={rate!r}", f"slot_frames:={slot_frames}"]

    def device_slot_frames(self) -> int:
        """F of a device's slot, in the frames its camera plays (one in ``every``)."""
        return self._played_slot()[0]

    def edge_args(self, index: int = 0, params_folder: Path | None = None) -> list[str]:
        """Edge ``index``'s command line: its devices, its share of the budget; a second edge
        on is renamed (``edge_mapper_2`` …) and reads the parameter file's ``edge_mapper``
        section from a copy under its own name in ``params_folder``."""
        f = self.fleet
        block = f.blocks()[index]
        args = self.node_args("edge_mapper")
        if index:
            if params_folder is None:
                raise ValueError("a second edge needs a folder for its parameter file")
            name = f.edge_names()[index]
            at = args.index("--params-file") + 1
            args[at] = str(renamed_params(Path(args[at]), "edge_mapper", name, params_folder))
            args[at + 1:at + 1] = ["-r", f"__node:={name}"]
        args += ["-p", f"devices:=[{', '.join(block)}]",
                 "-p", f"allocator:={f.allocator}", "-p", f"min_keyframes:={f.min_keyframes}"]
        if f.vmax_total:
            args += ["-p", f"vmax_total:={f.edge_shares()[index]}"]
        if f.merge_maps:
            args += ["-p", "merge_maps:=true"]
        if f.join_maps:
            args += ["-p", "merge_join:=true"]
        return args

    def device_args(self, name: str, index: int, params_file: Path | None = None
                    ) -> list[str]:
        """``name`` (device or player) of device ``index``: its namespace, walk and seed;
        ``params_file`` (default: the run's) the file it reads, keyed for its namespace
        (:func:`~twinslam.live.launcher.namespaced_params`)."""
        device = self.fleet.names()[index]
        sequence, start = self.starts[index]
        c = replace(self.config, sequence=sequence, start=start,
                    params_file=params_file or self.config.params_file)
        saved, self.config = self.config, c
        try:
            args = self.node_args(name)
        finally:
            self.config = saved
        args += ["-r", f"__ns:=/{device}", "-p", f"map_frame:={own_map_frame(device)}"]
        every = self.fleet.every
        if name == "device_tracker":
            args += ["-p", f"seed:={self.fleet.device_seed(index)}",
                     "-p", f"odom_frame:={device}/odom"]
        else:
            args += ["-p", f"frame_id:={device}/camera"]
            if self.fleet.orders:                # after the scenario's: the last one holds
                args += ["-p", f"order:={self.fleet.orders[index]}"]
            if self.fleet.delays:
                args += ["-p", f"start_delay_s:={float(self.fleet.delays[index])!r}"]
            if every > 1:
                args += ["-p", f"every:={every}", "-p", f"phase:={self.fleet.phase(index, start)}"]
            if self.config.pace_frames:       # one recording clock: the walks meet in time
                args += ["-p", f"pace_group:={PACE_GROUP}"]
        return args

    def end_playback(self) -> None:
        """Not for a fleet: each device's player plays its own walk to its end."""
        raise NotImplementedError("a fleet's players each play their walk to its end; "
                                  "end_playback ends a single device's run")

    def run_fleet(self) -> FleetReport:
        """Play every device's walk at once and report each."""
        with self.domain.monitor_scope():
            return self._run_fleet()

    def _run_fleet(self) -> FleetReport:
        c, names = self.config, self.fleet.names()
        sessions = {d: RosSession("twinslam_monitor", namespace=f"/{d}", executor="events")
                    for d in names}
        params_folder = tempfile.TemporaryDirectory(prefix="twinslam-fleet-")
        try:
            monitors = {d: PipelineMonitor(s.node, self._status(d)) for d, s in sessions.items()}
            self.records = monitors
            started = time.monotonic()
            self._start_edges(sessions, monitors, params_folder.name)
            # each device and player runs under its device's namespace
            namespaced = namespaced_params(c.params_file, Path(params_folder.name))
            for i, d in enumerate(names):
                for node in ("device_tracker", "sequence_player"):
                    self.procs[f"{node}:{d}"] = self.domain.spawn(
                        self.device_args(node, i, namespaced), host=d,
                        forks=preloaded_nodes())
            players = [self.procs[f"sequence_player:{d}"] for d in names]
            deadline = started + c.timeout_s

            def spin_all(until: Callable[[], bool], seconds: float) -> bool:
                end = time.monotonic() + seconds
                while time.monotonic() < end and not until():
                    for s in sessions.values():
                        s.spin_once(0.02)
                return until()

            spin_all(lambda: all(p.poll() is not None for p in players)
                     or self._failed_fleet() is not None, c.timeout_s)
            failed = self._failed_fleet()
            if failed:
                _, _, err = self.domain.stop(self.procs.pop(failed))
                raise RuntimeError(f"{failed} exited during the run: {err.strip()[-800:]}")
            # a player that could not play (a parameter refused, a sequence it cannot read)
            # leaves its device nothing to report: the run failed, it has no table
            for d, player in zip(names, players, strict=True):
                if player.returncode not in (0, None):
                    _, _, err = self.domain.stop(self.procs.pop(f"sequence_player:{d}"))
                    # a player stuck in DDS at its very end (it played everything) lost
                    # no run
                    if not ended_as_asked(player.returncode, err):
                        raise RuntimeError(f"sequence_player:{d} exited with "
                                           f"{player.returncode}: {err.strip()[-500:]}")
            expected = self.expected_slots()
            spin_all(lambda: all(
                (expected is None or expected - 1 in m.record.stats) for m in monitors.values()),
                min(60.0, max(10.0, deadline - time.monotonic())))
            spin_all(lambda: False, 0.5)
            slot_frames = self.device_slot_frames()
            elapsed = time.monotonic() - started
            reports = [report(c.policy, monitors[d].record, elapsed, slot_frames) for d in names]
            frames = [sum(len(s.frames) for s in monitors[d].record.summaries.values())
                      for d in names]
            budgets = [_mean_budget(monitors[d]) for d in names]
            records = {d: monitors[d].record for d in names}
            places = {d: self.fleet.place_of(i) for i, d in enumerate(names)}
            return FleetReport(self.fleet.allocator, names, reports, budgets, frames,
                               cross_device_errors(records, places),
                               merged_across_places(records, places),
                               merged_in_place(records, places),
                               cross_device_errors(records, places, LATE_SHARE),
                               joined_at(records))
        finally:
            self.stop()
            for s in sessions.values():
                s.close()
            params_folder.cleanup()

    def _start_edges(self, sessions: dict[str, RosSession],
                     monitors: dict[str, PipelineMonitor], params_folder: str) -> None:
        """Every edge started, each up once the last of its devices hears its requests'
        publisher; RuntimeError naming one that did not come up or exited."""
        f, timeout = self.fleet, min(120.0, self.config.timeout_s)
        for e, (name, host) in enumerate(zip(f.edge_names(), f.edge_hosts(), strict=True)):
            self.procs[name] = self.domain.spawn(self.edge_args(e, Path(params_folder)),
                                                 host=host, forks=preloaded_nodes())
        for name, block in zip(f.edge_names(), f.blocks(), strict=True):
            edge, last = self.procs[name], block[-1]

            def up(e: NodeProcess = edge, d: str = last) -> bool:
                return monitors[d].requests.get_publisher_count() > 0 or e.poll() is not None

            if not sessions[last].spin_until(up, timeout):
                raise RuntimeError(f"{name} did not come up within {timeout:.0f} s")
            if edge.poll() is not None:
                _, _, err = self.domain.stop(self.procs.pop(name))
                raise RuntimeError(f"{name} exited with {edge.returncode} at start: "
                                   f"{err.strip()[-500:]}")

    def slot_period_s(self) -> float:
        """Wall seconds a device's slot spans: its F frames at the recorded frame rate, played
        at ``rate`` × it — the time the edge has for the slot's map before the device tracks
        its next slot (a half-speed run's slot lasts 2 s, not 1; its maps' latencies are wall
        time)."""
        slot_frames, rate = played_device_slot(self._device_given(), rate=self.config.rate)
        return slot_frames / rate

    def _status(self, device: str) -> Callable[[MapStats, RunLog], None]:
        own = own_map_frame(device)
        merged: list[str] = []

        def line(msg: MapStats, _record: RunLog) -> None:
            frame = str(msg.header.frame_id)
            if self.echo and frame not in ("", own) and not merged:
                merged.append(frame)          # the edge merged its map into another's frame
                self.echo(f"[{self.config.policy} {device}] slot {msg.slot:>3} | its map "
                          f"merged into {frame}")
            if self.echo:
                self.echo(f"[{self.config.policy} {device}] slot {msg.slot:>3} | map "
                          f"{msg.map_size:>3} of {msg.keyframe_budget:>3} kf | lost "
                          f"{msg.lost_share:4.0%} | edge {msg.slot_processing_ms:5.0f} ms")
        return line

    def _failed_fleet(self) -> str | None:
        return next((name for name, proc in self.procs.items()
                     if not name.startswith("sequence_player") and proc.pid not in self._killed
                     and proc.poll() not in (None, 0)), None)


def posed_by_map_frame(record: RunLog, last_share: float = 1.0
                       ) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """A device's tracked frames with a true pose, as (published pose, true pose), grouped
    by the frame of the map each was tracked on (its map update's header: the device's own
    map frame, or the frame of a device its map was merged into); frames tracked on a map
    the record lacks are left out. ``last_share`` < 1 keeps only that share of the device's
    frames, its last by stamp (:data:`LATE_SHARE`)."""
    frame_of = {m.version: m.frame_id for m in record.maps.values()}
    grouped: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    keys = sorted(time_key(f.stamp) for s in record.summaries.values() for f in s.frames)
    first_kept = keys[len(keys) - math.ceil(len(keys) * last_share)] if keys else 0
    for summary in record.summaries.values():
        for f in summary.frames:
            key = time_key(f.stamp)
            frame = frame_of.get(int(f.map_version))
            if key < first_kept:
                continue
            if f.tracked and frame and key in record.poses and key in record.ground_truth:
                grouped.setdefault(frame, []).append((record.poses[key],
                                                      record.ground_truth[key]))
    return grouped


#: the share of each device's frames, its last, the late cross-device figure scores: after
#: the merges in the runs measured, so two settings whose merges come at different times are
#: compared on the same frames (the whole figure counts only frames after a merge, and a later
#: merge leaves out the ground just after it). Empty where the last thirds see no one place
#: (two devices from a corridor's two ends end at its two ends)
LATE_SHARE = 1 / 3


def cross_device_errors(records: dict[str, RunLog], places: Mapping[str, int] | None = None,
                        last_share: float = 1.0) -> dict[tuple[str, str], RevisitError]:
    """For each pair of devices (in the fleet's order) that walk one place (``places``: each
    device's; None: all one), the cross-device revisit error over their frames tracked on
    maps in one frame, each frame of one paired only with the other's in the same map frame
    (:func:`posed_by_map_frame`; the true poses in the sequence's world frame, which every
    device of one sequence shares): content one device anchored as the other sees it.
    Devices never in one frame have no pair; devices of two places are no pair at all
    (their true poses are in two worlds: :func:`merged_across_places`). ``last_share``: over
    that share of each device's frames, its last (:func:`posed_by_map_frame`)."""
    grouped = {d: posed_by_map_frame(r, last_share) for d, r in records.items()}
    names = list(records)
    place = places or {}
    return {(a, b): cross_device_revisit_error_by_frame(grouped[a], grouped[b])
            for i, a in enumerate(names) for b in names[i + 1:]
            if place.get(a, 0) == place.get(b, 0)}


def merged_across_places(records: dict[str, RunLog], places: Mapping[str, int]
                         ) -> list[tuple[str, str]]:
    """The pairs of devices walking two places that were ever tracked on maps in one frame:
    the edge merged maps of two places, a false merge."""
    return _in_one_frame(records, places, same_place=False)


def own_map_frame(device: str) -> str:
    """The frame a fleet's device names its map in (``ar2/map``), and its edge its updates
    until the device's map joins another's place."""
    return f"{device}/map"


def joined_at(records: dict[str, RunLog]) -> dict[str, tuple[int, str]]:
    """Each device whose map joined another device's frame: the first of its slots whose map
    update came in a frame not its own (:func:`own_map_frame`), and that frame — when the
    edge merged its map into a place another device started. How soon a device coming to a
    mapped place joins decides how long it uploads as if alone, and only a live run shows
    it: in process the looks wait for nothing (docs/results/shared-map.md, "The words
    learned beside the looks"). A device that kept its own frame (alone, or a place's first)
    is left out."""
    joined = {}
    for device, record in records.items():
        own = own_map_frame(device)
        moved = [(slot, m.frame_id) for slot, m in sorted(record.maps.items())
                 if m.frame_id and m.frame_id != own]
        if moved:
            joined[device] = moved[0]
    return joined


def merged_in_place(records: dict[str, RunLog], places: Mapping[str, int] | None = None
                    ) -> list[tuple[str, str]]:
    """The pairs of devices of one place (``places``: each device's; None: all one) ever
    tracked on maps in one frame: merged, whether or not any of their frames saw one view
    (two devices walking a corridor towards each other see its places from opposite ways,
    and the cross-device error has no pair)."""
    return _in_one_frame(records, places or {}, same_place=True)


def _in_one_frame(records: dict[str, RunLog], places: Mapping[str, int], same_place: bool
                  ) -> list[tuple[str, str]]:
    """The pairs of devices (in the fleet's order) of one place or of two, as asked, ever
    tracked on maps in one frame."""
    frames = {d: set(posed_by_map_frame(r)) for d, r in records.items()}
    names = list(records)
    return [(a, b) for i, a in enumerate(names) for b in names[i + 1:]
            if (places.get(a, 0) == places.get(b, 0)) == same_place and frames[a] & frames[b]]


def _mean_budget(monitor: PipelineMonitor) -> float:
    budgets = [int(s.keyframe_budget) for s in monitor.record.stats.values()]
    return float(np.mean(budgets)) if budgets else math.nan


def print_fleet_table(fleet: FleetReport, echo: Callable[[str], None] = print) -> None:
    """One row a device (labelled by it), their mean, and Jain's index of the tracked
    shares, under the policy and allocator."""
    policy = fleet.reports[0].label if fleet.reports else "?"
    echo(f"{policy}, allocator {fleet.allocator}: {len(fleet.devices)} devices")
    echo(f"{RunReport.HEADER.replace('policy', 'device', 1)} {'budget':>7} {'tracked':>8}")
    shares = fleet.tracked_shares()
    for device, r, budget, share in zip(fleet.devices, fleet.reports, fleet.budgets, shares,
                                        strict=True):
        echo(f"{r.row().replace(r.label.ljust(14), device.ljust(14), 1)} {budget:>7.1f} "
             f"{share:>8.1%}")
    mean = [float(np.nanmean([getattr(r, k) for r in fleet.reports]))
            for k in ("mean_uncertainty", "lost_share", "tracked_uncertainty", "ate_m")]
    head = f"{'mean':<14} {mean[0]:>10.1f} {mean[1]:>6.1%} {mean[2]:>10.1f} {mean[3]:>7.3f}"
    echo(f"{head:<{len(RunReport.HEADER)}} {float(np.nanmean(fleet.budgets)):>7.1f} "
         f"{float(np.nanmean(shares)):>8.1%}")
    echo(f"Jain's index of the tracked shares: {fleet.jain_tracked:.3f}")
    for device, r in zip(fleet.devices, fleet.reports, strict=True):
        if (line := r.pieces_line(device)) is not None:
            echo(line)
    for line in merge_lines(fleet):
        echo(line)


def merge_lines(fleet: FleetReport) -> list[str]:
    """What the fleet's maps made of its places: when each device's map joined another's
    frame; each pair of one place's devices' cross-device revisit error, or that they never
    shared a map frame, or that they did with no pair of frames seeing one view; and each
    false merge across two places."""
    lines = [f"{device}'s map joined {frame} at its slot {slot}"
             for device, (slot, frame) in fleet.joined.items()]
    for (a, b), e in fleet.cross_device.items():
        if e.pairs:
            where = (f"RMS {e.rms_m * 100:.1f} cm, median {e.median_m * 100:.1f} cm over "
                     f"{e.pairs} pairs of frames in one map frame")
            late = fleet.cross_device_late.get((a, b))
            if late is not None and late.pairs:
                where += (f"; over the last third of each one's frames RMS "
                          f"{late.rms_m * 100:.1f} cm ({late.pairs} pairs)")
        elif (a, b) in fleet.merged:
            where = (f"no pair: in one map frame, but no frame of one within "
                     f"{REVISIT_RADIUS_M:g} m and {REVISIT_ANGLE_DEG:g}° of one of the other's "
                     "(they saw the place from other ways)")
        else:
            where = "never in one map frame"
        lines.append(f"cross-device revisit error {a}-{b}: {where}")
    lines += [f"devices {a} and {b} walk two places but were tracked on maps in one frame: "
              "the edge merged two places (a false merge)"
              for a, b in fleet.merged_across_places]
    return lines


#: the columns of a fleet run's rows (``twinslam launch --devices N --out DIR``: fleet_runs.csv)
FLEET_COLUMNS = ("policy", "allocator", "seed", "device", "slots", "frames", "mean_uncertainty",
                 "lost_share", "tracked_uncertainty", "untracked_frames", "tracking_failures",
                 "relocalisations", "ate_m", "mean_budget", "frames_dropped", "edge_ms_median",
                 "latency_ms_median", "late_slots", "cross_device_rms_m", "cross_device_pairs",
                 "frames_uploaded", "cross_device_late_rms_m", "cross_device_late_pairs",
                 "map_in_pieces_slots", "joined_at_slot")


def fleet_rows(fleet: FleetReport, seed: int, records: dict[str, RunLog],
               slot_period_s: float) -> list[dict[str, object]]:
    """One row a device of ``fleet``: its figures, its mean share of V_total, how many of its
    slots' maps came later than ``slot_period_s`` after its summaries, and the slot its map
    joined another device's frame at (NaN: never)."""
    rows: list[dict[str, object]] = []
    for device, r, budget, frames in zip(fleet.devices, fleet.reports, fleet.budgets,
                                         fleet.frames, strict=True):
        stats = list(records[device].stats.values())
        latency = [s.slot_latency_ms for s in stats if math.isfinite(s.slot_latency_ms)]
        rows.append({"policy": r.policy, "allocator": fleet.allocator, "seed": seed,
                     "device": device, "slots": r.slots, "frames": frames,
                     "mean_uncertainty": r.mean_uncertainty, "lost_share": r.lost_share,
                     "tracked_uncertainty": r.tracked_uncertainty,
                     "untracked_frames": r.untracked_frames,
                     "tracking_failures": r.tracking_failures,
                     "relocalisations": r.relocalisations, "ate_m": r.ate_m,
                     "mean_budget": budget, "frames_dropped": r.frames_dropped,
                     "edge_ms_median": r.edge_ms_median,
                     "latency_ms_median": float(np.median(latency)) if latency else math.nan,
                     "late_slots": sum(1 for v in latency if v > slot_period_s * 1000),
                     **_cross_cells(fleet.cross_device, device, "cross_device"),
                     **_cross_cells(fleet.cross_device_late, device, "cross_device_late"),
                     "frames_uploaded": r.frames_uploaded,
                     "map_in_pieces_slots": r.map_in_pieces_slots,
                     "joined_at_slot": (fleet.joined[device][0] if device in fleet.joined
                                        else math.nan)})
    return rows


def _cross_cells(errors: Mapping[tuple[str, str], RevisitError], device: str, column: str
                 ) -> dict[str, float]:
    """A device's cross-device revisit error against every other device, over all its pairs
    (RMS of the pairs' RMS weighted by their counts), and the pairs: ``COLUMN_rms_m``,
    ``COLUMN_pairs``."""
    mine = [e for pair, e in errors.items() if device in pair and e.pairs]
    pairs = sum(e.pairs for e in mine)
    rms = math.sqrt(sum(e.rms_m ** 2 * e.pairs for e in mine) / pairs) if pairs else math.nan
    return {f"{column}_rms_m": rms, f"{column}_pairs": float(pairs)}

