"""How many devices one edge keeps up with: one ``edge_mapper`` process serving N
emulated devices, edge compute per device-slot, the latency from a slot's summaries to its map
update, and the share of device-slots whose map came later than a slot period (missed
deadlines: the device then tracks its next slot on an older map), for N = 1, 2, 4, ….

Real device trackers cost ~13 CPU ms a frame each, so on this 2-core machine three of them
and their cameras already load both cores and the edge would be measured starved of CPU by its
own clients. The devices are emulated instead: one live run of the pipeline is recorded
(``twinslam launch --record``: the device's frame summaries and every keyframe it uploaded),
and each emulated device replays that protocol into its own namespace at the recorded pace —
summaries every slot period (the recorded device's: its frames a slot at its frame rate), the
keyframes the edge asks for paced at d_k — from this process
(no tracking, no images). The edge does its whole work per device: plan, integrate, GTSAM,
the keyframe budget (V_total = 45 × N, equal shares), map updates and viewer topics (these
are made only while something subscribes: nothing does here).

A replayed device reports the map point ids the recorded edge made, so a recording measures
only an edge that names its points as the recording's did: one that integrates otherwise (a
look-alike point chosen otherwise among equals) lacks the ids its devices report, finds their
frames lost, and asks for and restores other keyframes than the recording's. The ``lost``
column (the planned slots' lost share, as the edge counts it) shows it: a few percent on a
recording of the same code, most of the frames where the ids no longer meet — then record
again.

``ms/answer`` is the edges' CPU over the run (every thread of every edge process) for each
device-slot they answered, in ms of a core: what a device-slot costs the edge. N devices at
1 s slots on C cores leave C × 1000 / N ms for everything. ``slot thr`` is how busy the edges'
slot threads (their main threads, each serving all its devices) were, a share of the run's
wall time each; most of the rest of an edge process's CPU is its loop closer's worker, the two
threads sharing one interpreter. Where the edges take all the cores they get and the run ends
at its deadline with slots unanswered, ``ms/answer`` measures the run's length over its
answers rather than the work (fifty devices on two edge processes on 2026-12-05: 55–56 ms
whatever the slot cost); compare work where the edges keep up.
The emulated devices share the host with the edges: ``devices CPU`` is this process's own
(the replay and its DDS traffic, in cores) and ``idle`` the share of the host's cores that
nothing used while the fleet ran. Where slots are late with cores idle, the edges' own serial
work is what limits (one Python interpreter works on one core at a time); where none is idle,
the host's CPU is, and the devices' part of it would be on their own machines in a real fleet.
The emulator spins on rclpy's ``EventsExecutor``, as the nodes do (``--emulator-executor``);
until 2026-12-05 it spun a ``SingleThreadedExecutor``, whose turns build a wait set of every
device's topics in Python — 78 % of the emulator's thread at fifty devices (py-spy).

With ``--edges K`` the devices are split into K blocks of neighbours, each served by an
``edge_mapper`` process of its own (what ``twinslam launch --devices N --edges K`` starts); the
CPU is theirs together. With ``--places P`` of at least K, each edge serves whole places
instead (a place's maps merge within one edge process; before 2026-12-04 the blocks were of
neighbours there too, and a place's devices k and k + P could land on different edges).
With ``--hosts`` each edge process runs on an edge host of its own
(``edge``, ``edge2``, …: network namespaces on a switch, :mod:`twinslam.hosts.netns`, as
``twinslam launch --hosts --edges K`` places them) and the emulated devices on a host
``device``: every message crosses a veth and the bridge over UDP with static discovery peers,
as between machines on a LAN — the hosts still share this machine's cores (needs root).
``--edge-cores "0-1 0-1 2-3 2-3"`` holds edge process k to the k-th CPU list (cycled) and
``--device-cores 4-15`` the emulated devices to theirs (:mod:`twinslam.hosts.cpu_sets`): on a
machine of enough cores, four edge processes on two emulated 2-core edge hosts measured in one
run, each host's processes competing for its own two cores only; the ``idle`` column is then
the edges' cores' idle share.
``--pools cores`` runs the edges with the math libraries' thread pools
at a thread a core, as every node had them before they were kept to one
(:mod:`twinslam.node_runtime.math_threads`): ``--pools cores,one`` measures both in one run.

``--merge-maps on`` runs the edges with ``merge_maps:=true``: every emulated device replays the
one recorded walk, so the devices of an edge process all walk one place — each looks for it
in the others' maps until it merges, then adopts every keyframe the others upload and welds
it to its own points (:mod:`edge_mapper.place_merging`). That is the most a place can cost
the edge (every device shares it); ``--merge-maps off,on`` measures it beside the unshared
fleet in one run, and the table counts the merges made. The replay is not the shared fleet's
own, though: a shared place asks each device for fewer of its frames (the shared map covers
their views), so later summaries report points of keyframes the run never integrated, and
``lost`` shows it (31 % at eight devices against 2 % unshared; 76–78 % with eight devices
spread along the corridor walked twice, ``--stagger 40``: a device that comes to ground others
mapped uploads little of it). ``bench.place_walks`` measures a shared place with each device
tracking on the map the edge sends it instead, in one process.

``--places P`` makes the fleet walk P places: device k replays the recording as place
k mod P, every keyframe's ORB descriptors XORed with a 256-bit mask of that place's own
(:meth:`Recording.of_place`; place 0 is the recording). A device's own map matches,
integrates and closes loops as the recording's did (XOR keeps every Hamming distance within
a place), while no descriptor of one place is near another's: place recognition relates no
two places, as the maps of two buildings. With ``--merge-maps on`` the devices of a place
merge and the others look for their place after every slot, as a fleet of which only some
share a place does (``--devices 16 --places 8``: every place walked by two). Where some
places are walked by several devices and others by one (``--devices 50 --places 38``: twelve
pairs, twenty-six alone), a line under the row gives each half's late share, median slot
compute, restores a device-slot and lost share apart (:func:`by_sharing`; the CSV's
``*_sharing`` and ``*_alone`` columns).

The devices' starts are spread over one slot period (``--stagger 1``): each sends its
summaries at a phase of its own, but all of them walk the recording in step, so the slots
where they come back and restore keyframes fall together — the worst a fleet can do to an
edge. ``--stagger S`` spreads the starts over S periods instead, each device at a place of
the walk of its own, as devices that joined at different times are (the fleet is then whole
only from the last start to the first end: the first devices walk alone at first, the last
alone at the end, where they come back).

``--collector-log`` times every garbage collection in the edge processes (a
``sitecustomize`` hook, ``bench/collector_watch``, on their ``PYTHONPATH``) and reports each
setting's full collections: a full collection stalls every device the process serves.

    python -m bench.edge_scaling [--devices 1,2,4,8,12,16] [--edges 1,2] [--pools one]
                                 [--merge-maps off] [--stagger 1] [--checkpoint-every 0]
                                 [--hosts] [--recording DIR] [--csv FILE] [--slots-csv FILE]
                                 [--slots-plot PNG] [--collector-log]
                                 [--merge-maps on --lend-in-view on|off --unseen-slots N]
                                 [--places P] [--edge-param NAME:=VALUE …]
                                 [--edge-cores "LIST LIST …" --device-cores LIST]

``--edge-param NAME:=VALUE`` (repeatable) hands any ROS parameter to every edge process, as
``-p`` does: a setting the bench has no option for, compared run by run in one tree
(``loop_closing:=false``: what the fleet costs without the loop closer's worker).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    UplinkThroughput,
    UploadRequest,
)

from bench.paths import REPO, SEVEN_SCENES
from msg_schemas import qos, topics
from twinslam.hosts.cpu_sets import (
    CpuSetError,
    cycled,
    format_cpu_list,
    held_to,
    parse_cpu_list,
    usable,
)
from twinslam.hosts.loopback import LoopbackDomain, ProcessDomain
from twinslam.hosts.netns import NetnsHosts, unavailable_reason
from twinslam.live.fleet import edge_blocks, edge_hosts
from twinslam.node_runtime.session import EXECUTORS, RosSession
from twinslam.node_runtime.thread_cpu import stat_cpu
from twinslam.reporting import pyplot, write_dict_rows
from twinslam.slot_protocol import table1

SEVEN = SEVEN_SCENES
#: the line a device's edge logs when its map moved into another device's place
MOVED_LINE = re.compile(r"slot \d+: map (?:merged into|joined) ")
#: the longest the emulator sleeps without looking at its clock (a device that is due sends
#: at most this late when no message wakes the spin first)
SPIN_AT_MOST_S = 0.05
#: what ``--edge-param`` takes: a ROS parameter's name, ``:=``, a value
EDGE_PARAM = re.compile(r"[A-Za-z][A-Za-z0-9_./]*:=\S.*")
#: the edge parameters the bench sets itself, and the option that sets each ("": none — the
#: fleet's own): ``--edge-param`` refuses them, a second value would silently win or lose
BENCH_SETS = {"devices": "--devices", "vmax_total": "", "allocator": "", "slot_timeout_s": "",
              "policy": "--policy", "compute_budget": "--compute-budget",
              "merge_maps": "--merge-maps", "checkpoint": "--checkpoint-every",
              "checkpoint_every": "--checkpoint-every",
              "checkpoint_in_background": "--checkpoints-in-background",
              "loop_worker_niceness": "--loop-worker-niceness",
              "loop_worker_share": "--loop-worker-share",
              "loop_worker_yields": "--loop-worker-yields",
              "loops_across_devices": "--loops-across", "lend_in_view": "--lend-in-view",
              "lent_unseen_slots": "--unseen-slots"}
#: the slot period when a recording tells none (Table I's)
SLOT_S = table1.SLOT_FRAMES / table1.FRAME_RATE_HZ


@dataclass
class Recording:
    """One device's side of a recorded run: summaries by slot, keyframes by frame id."""

    summaries: dict[int, bytes]
    rates: dict[int, float]
    keyframes: dict[int, bytes]
    #: the recorded device's slot period, seconds (its frames a slot at its frame rate): the
    #: pace the emulated devices replay it at
    slot_s: float = SLOT_S
    slots: list[int] = field(init=False, default_factory=list)     #: the recorded slots, in order

    def __post_init__(self) -> None:
        self.slots = sorted(self.summaries)

    def of_place(self, place: int) -> Recording:
        """This walk as one of another place that looks like no other: every keyframe's ORB
        descriptors XORed with a 256-bit mask drawn for ``place`` (0: the recording itself).
        XOR keeps each Hamming distance between two of its descriptors, so the place's own
        map is built as the recording's was; a descriptor of another place lies ~128 bits
        from each of its own."""
        if place == 0:
            return self
        mask = np.random.default_rng(place).integers(0, 256, 32, dtype=np.uint8)
        keyframes = {}
        for frame, raw in self.keyframes.items():
            kf = deserialize_message(raw, Keyframe)
            kf.descriptors = (np.asarray(kf.descriptors, dtype=np.uint8).reshape(-1, 32)
                              ^ mask).reshape(-1)
            keyframes[frame] = bytes(serialize_message(kf))
        return Recording(self.summaries, self.rates, keyframes, self.slot_s)

    @classmethod
    def read(cls, folder: Path) -> Recording:
        summaries, rates, keyframes = {}, {}, {}
        sizes: list[int] = []
        stamps: list[float] = []
        with Reader(folder) as reader:
            for conn, _, raw in reader.messages():
                if conn.topic == "/" + topics.FRAME_SUMMARIES:
                    msg = deserialize_message(raw, FrameSummaries)
                    summaries[int(msg.slot)] = bytes(raw)
                    rates[int(msg.slot)] = float(msg.rate_mbps)
                    sizes.append(len(msg.frames))
                    stamps += [f.stamp.sec + f.stamp.nanosec * 1e-9 for f in msg.frames]
                elif conn.topic == "/" + topics.KEYFRAMES:
                    kf = deserialize_message(raw, Keyframe)
                    keyframes[int(kf.frame_id)] = bytes(raw)
        if not summaries:
            raise SystemExit(f"{folder}: no frame summaries recorded")
        steps = np.diff(sorted(stamps))
        steps = steps[steps > 0]
        slot_s = float(np.median(sizes) * np.median(steps)) if steps.size else SLOT_S
        return cls(summaries, rates, keyframes, slot_s)


@dataclass
class EmulatedDevice:
    """A device namespace replaying a recording against the edge."""

    name: str
    recording: Recording
    start: float
    pubs: dict[str, Any] = field(default_factory=dict)
    next_slot: int = 0
    sent_at: dict[int, float] = field(default_factory=dict)
    uploads: list[tuple[float, int, bytes | None]] = field(default_factory=list)  #: due, slot
    stats: dict[int, MapStats] = field(default_factory=dict)
    missing: int = 0                                 #: keyframes asked for, not recorded
    sent: dict[int, int] = field(default_factory=dict)    #: keyframes sent, by slot

    def tick(self, now: float) -> None:
        if now >= self.summaries_due:
            slot = self.recording.slots[self.next_slot]
            self.pubs["summaries"].publish(self.recording.summaries[slot])
            self.sent_at[slot] = now
            self.next_slot += 1
        while self.uploads and self.uploads[0][0] <= now:
            _, slot, raw = self.uploads.pop(0)
            if raw is not None:
                self.pubs["keyframes"].publish(raw)
            else:                                    # the slot's uploads are done: its account
                self._throughput(slot)

    def on_stats(self, msg: MapStats) -> None:
        """The edge's statistics of one of this device's slots."""
        self.stats[int(msg.slot)] = msg

    def on_request(self, msg: UploadRequest) -> None:
        slot, now = int(msg.slot), time.monotonic()
        rate = max(self.recording.rates.get(slot, 40.0), 1e-3)
        due = now
        self.sent[slot] = 0
        for frame in msg.upload_frame_ids:
            raw = self.recording.keyframes.get(int(frame))
            if raw is None:
                self.missing += 1
                continue
            due += table1.ALPHA_MBIT / rate            # a frame occupies α at d_k
            self.uploads.append((due, slot, raw))
            self.sent[slot] += 1
        self.uploads.append((due, slot, None))
        self.uploads.sort(key=lambda u: (u[0], u[2] is None))

    def _throughput(self, slot: int) -> None:
        n = self.sent.get(slot, 0)
        rate = self.recording.rates.get(slot, 40.0)
        msg = UplinkThroughput(slot=slot, configured_rate_mbps=rate, rate_state=0,
                               achieved_mbps=rate if n else 0.0,
                               bytes_sent=int(n * table1.ALPHA_MBIT * 1e6 / 8),
                               duration_s=n * table1.ALPHA_MBIT / rate, frames_sent=n)
        self.pubs["throughput"].publish(msg)

    @property
    def done(self) -> bool:
        return self.next_slot >= len(self.recording.summaries)

    @property
    def summaries_due(self) -> float:
        """When its next slot's summaries are due (inf: every slot sent)."""
        return math.inf if self.done else self.start + self.next_slot * self.recording.slot_s

    def next_due(self) -> float:
        """When this device next has something to send (its next slot's summaries, its next
        upload or account; inf: nothing more)."""
        due = self.summaries_due
        return min(due, self.uploads[0][0]) if self.uploads else due


def record(folder: Path) -> None:
    """One live run of 600 frames (7-Scenes sample, or the synthetic room) recorded."""
    sequence = str(SEVEN) if SEVEN.is_dir() else "synthetic:600"
    print(f"recording one device's protocol: 600 frames of {sequence} into {folder}", flush=True)
    subprocess.run([sys.executable, "-m", "twinslam.cli.main", "launch", "--loopback",
                    "--sequence", sequence, "--frames", "600", "--policy", "lff", "--record",
                    str(folder), "--record-camera-every", "1000000", "--out",
                    str(folder.parent / "pictures")], check=True, cwd=REPO,
                   stdout=subprocess.DEVNULL)


def edge_devices(names: list[str], edges: int, places: int) -> list[list[str]]:
    """Each edge process's devices: with at least as many places as edges (device k walks
    place k mod ``places``), whole places an edge — maps merge within one edge process, as
    ``twinslam launch --sequence A,B --edges K`` gives each edge whole places — the places
    cut into runs holding as even a share of the devices as whole places allow; else runs of
    neighbouring devices (:func:`edge_blocks`)."""
    if places < max(edges, 2):
        return edge_blocks(names, edges)
    walkers = np.bincount(np.arange(len(names)) % places, minlength=places)
    before = np.concatenate([[0], np.cumsum(walkers)])        # devices of the places before p
    # edge e's first place: where the devices before it come nearest e/edges of them all
    first = [0, *(int(np.argmin(np.abs(before[1:-1] - e * len(names) / edges))) + 1
                  for e in range(1, edges)), places]
    for e in range(1, edges):              # a place at least an edge, in order
        first[e] = min(max(first[e], first[e - 1] + 1), places - (edges - e))
    return [[d for k, d in enumerate(names) if a <= k % places < b]
            for a, b in itertools.pairwise(first)]


def by_sharing(slots: list[dict[str, Any]], names: list[str], places: int, slot_s: float,
               slots_a_device: int) -> dict[str, float]:
    """The fleet's figures for the devices that share their place with another (device k
    walks place k mod ``places``) and for those alone in theirs, apart: a fleet of which half
    shares a place pays for the merges, the copies each map adopts and restores, and the
    frames a shared device's replay reports lost (its edge asked it for fewer keyframes than
    the recording's) on the sharing half only, and the mean over the fleet hides which half
    is late. Per group: devices, the late share of its device-slots (a map later than a slot
    period, or none), the median slot compute, restored keyframes a device-slot and the
    lost share — NaN for a group without devices or answers."""
    walkers = np.bincount(np.arange(len(names)) % max(places, 1), minlength=max(places, 1))
    sharing = {d for k, d in enumerate(names) if walkers[k % max(places, 1)] > 1}
    out: dict[str, float] = {}
    for group, members in (("sharing", sharing), ("alone", set(names) - sharing)):
        rows = [s for s in slots if s["device"] in members]
        late = sum(1 for s in rows if s["latency_ms"] > slot_s * 1000)
        expected = len(members) * slots_a_device
        out[f"devices_{group}"] = len(members)
        out[f"missed_share_{group}"] = ((late + expected - len(rows)) / expected
                                        if expected else math.nan)
        out[f"compute_ms_median_{group}"] = (float(np.median([s["compute_ms"] for s in rows]))
                                             if rows else math.nan)
        out[f"restored_a_slot_{group}"] = (float(np.mean([s["restored"] for s in rows]))
                                           if rows else math.nan)
        out[f"lost_share_{group}"] = (float(np.mean([s["lost_share"] for s in rows]))
                                      if rows else math.nan)
    return out


def cpu_seconds(pid: int, thread: int | None = None) -> float:
    """The CPU time (user + system, seconds) of process ``pid``, every thread, or of its
    thread ``thread`` alone (the main thread's id is the process's)."""
    stat = f"/proc/{pid}/stat" if thread is None else f"/proc/{pid}/task/{thread}/stat"
    return stat_cpu(Path(stat).read_text())[2]


def host_idle(cores: Collection[int] = ()) -> tuple[int, int]:
    """The host's idle and total CPU time so far (clock ticks, /proc/stat): what the edges,
    the emulated devices and everything else together left unused — on every core, or on
    ``cores`` only (the edges' own, where they are held to some)."""
    lines = Path("/proc/stat").read_text().splitlines()
    wanted = {f"cpu{c}" for c in cores} if cores else {"cpu"}
    idle = total = 0
    for line in lines:
        name, *values = line.split()
        if name in wanted:
            ticks = [int(v) for v in values]
            idle += ticks[3] + ticks[4]                # idle + iowait; without guest time
            total += sum(ticks[:8])
    return idle, total


#: the math libraries' pools: one thread (the nodes' default) or a thread a core (as before)
POOL_ENV = {"one": {}, "cores": {"OMP_NUM_THREADS": str(os.cpu_count() or 1),
                                 "OPENBLAS_NUM_THREADS": str(os.cpu_count() or 1)}}


@contextlib.contextmanager
def environment(values: dict[str, str | None]) -> Iterator[None]:
    """This process's environment (which the edges it starts inherit) with ``values`` set
    (None: unset) while it is open, as it was after."""
    saved = {k: os.environ.get(k) for k in values}

    def put(settings: dict[str, str | None]) -> None:
        for key, value in settings.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value

    put(values)
    try:
        yield
    finally:
        put(saved)


@contextlib.contextmanager
def pools_env(pools: str) -> Iterator[None]:
    """This process's environment (which the edges inherit) with ``pools``' variables."""
    if pools not in POOL_ENV:
        raise SystemExit(f"--pools: one of {', '.join(POOL_ENV)}, not {pools!r}")
    with environment({"OMP_NUM_THREADS": None, "OPENBLAS_NUM_THREADS": None,
                      **POOL_ENV[pools]}):
        yield


@contextlib.contextmanager
def fleet_network(edges: int, hosts: bool) -> Iterator[tuple[ProcessDomain, str | None]]:
    """Where a row runs: a loopback domain, or with ``hosts`` the hosts ``device``, ``edge``,
    ``edge2``, … (every row of a process the same set of names but for the edges: Fast DDS
    takes a process's interfaces from its first participant, and the device host keeps its
    address in every set, :meth:`NetnsHosts.address`); yields the domain and the devices'
    host (None on loopback), inside which this process's participant must be made."""
    if not hosts:
        with LoopbackDomain() as dom:
            dom.activate()
            yield dom, None
        return
    names = ("device", *edge_hosts(edges))
    with NetnsHosts(prefix=f"tsb{os.getpid()}-", domain_id=0, hosts=names) as net, \
            net.inside("device"):
        yield net, "device"


def measure(n: int, recording: Recording, policy: str, compute_budget: float = 0.0,
            edges: int = 1, pools: str = "one", hosts: bool = False,
            merge_maps: bool = False, stagger: float = 1.0, checkpoint_every: int = 0,
            niceness: int | None = None, share: float | None = None,
            yields: bool | None = None, background: bool | None = None,
            across: bool | None = None, in_view: bool | None = None,
            unseen: int | None = None, places: int = 1, executor: str = "events",
            extra: tuple[str, ...] = (), edge_cores: Sequence[frozenset[int]] = (),
            everywhere: frozenset[int] | None = None
            ) -> tuple[dict[str, float | str], list[dict[str, float | str]]]:
    """One fleet of ``n`` emulated devices served, their starts spread evenly over ``stagger``
    slot periods, each device's map checkpointed every ``checkpoint_every`` slots (0: never),
    the edges' loop workers ``niceness`` steps below their slots, at most ``share`` of a
    core and waiting for the slots' work or not (``yields``), the checkpoints written on a
    thread of their own or on the slot thread (``background``), their merged maps' loops
    closing with the other devices' keyframes or not (``across``), each map lent the other
    devices' keyframes once its device heads where it sees them or at once (``in_view``),
    a lent copy its device has not held nor seen for ``unseen`` slots given back (0: kept;
    None: the edge's defaults), device k walking place k mod ``places``
    (:meth:`Recording.of_place`), every edge given the ``extra`` parameters (``NAME:=VALUE``
    each, as ``-p`` takes them), edge process k held to CPU set k mod len(``edge_cores``)
    (none given: to ``everywhere``, or where this process may run); the table's row and every
    device-slot's figures (its latency, the edge's compute, what the slot restored, uploaded,
    closed)."""
    names = [f"ar{i + 1}" for i in range(n)]
    with pools_env(pools), fleet_network(edges, hosts) as (dom, _), \
            tempfile.TemporaryDirectory(prefix="twinslam-checkpoints-") as kept:
        served = edge_devices(names, edges, places)
        hosted = edge_hosts(len(served)) if hosts else [None] * len(served)
        pins = [pin if pin is not None else everywhere
                for pin in cycled(edge_cores, len(served))]
        edges_cores = frozenset().union(*edge_cores)
        procs = [dom.spawn(["-m", "edge_mapper.node", "--ros-args",
                            "-r", f"__node:=edge_mapper_{e + 1}", "-p", f"policy:={policy}",
                            "-p", f"devices:=[{', '.join(block)}]",
                            "-p", f"vmax_total:={45 * len(block)}",
                            "-p", "allocator:=equal", "-p", "slot_timeout_s:=5.0",
                            "-p", f"compute_budget:={compute_budget}",
                            "-p", f"merge_maps:={str(merge_maps).lower()}",
                            *(["-p", f"checkpoint:={kept}/edge{e + 1}.npz",
                               "-p", f"checkpoint_every:={checkpoint_every}"]
                              if checkpoint_every else []),
                            *(["-p", "checkpoint_in_background:="
                               f"{str(background).lower()}"]
                              if checkpoint_every and background is not None else []),
                            *(["-p", f"loop_worker_niceness:={niceness}"]
                              if niceness is not None else []),
                            *(["-p", f"loop_worker_share:={share}"]
                              if share is not None else []),
                            *(["-p", f"loop_worker_yields:={str(yields).lower()}"]
                              if yields is not None else []),
                            *(["-p", f"loops_across_devices:={str(across).lower()}"]
                              if across is not None else []),
                            *(["-p", f"lend_in_view:={str(in_view).lower()}"]
                              if in_view is not None else []),
                            *(["-p", f"lent_unseen_slots:={unseen}"]
                              if unseen is not None else []),
                            *itertools.chain.from_iterable(("-p", e) for e in extra)],
                           host=hosted[e], **held_to(pins[e]))
                 for e, block in enumerate(served)]
        for edge, block in zip(procs, served, strict=True):
            if not dom.wait_for_log(edge, f"listening on /{block[-1]}", 120):
                raise SystemExit(f"an edge did not come up: {dom.log(edge)[-2000:]}")
        with RosSession("bench_devices", executor=executor) as ros:
            now = time.monotonic() + 2.0
            walks = [recording.of_place(p) for p in range(places)]
            devices = [EmulatedDevice(d, walks[i % places],
                                      now + i * stagger * recording.slot_s / n)
                       for i, d in enumerate(names)]
            for dev in devices:
                pub, sub = ros.node.create_publisher, ros.node.create_subscription
                dev.pubs = {"summaries": pub(FrameSummaries,
                                             f"{dev.name}/{topics.FRAME_SUMMARIES}",
                                             qos.PROTOCOL),
                            "keyframes": pub(Keyframe, f"{dev.name}/{topics.KEYFRAMES}",
                                             qos.PROTOCOL),
                            "throughput": pub(UplinkThroughput,
                                              f"{dev.name}/{topics.UPLINK_THROUGHPUT}",
                                              qos.PROTOCOL)}
                sub(UploadRequest, f"{dev.name}/{topics.UPLOAD_REQUEST}", dev.on_request,
                    qos.PROTOCOL)
                sub(MapStats, f"{dev.name}/{topics.MAP_STATS}", dev.on_stats, qos.PROTOCOL)
            ready = ros.spin_until(lambda: all(
                d.pubs["summaries"].get_subscription_count() > 0 for d in devices), 30.0)
            if not ready:
                raise SystemExit("the edge did not subscribe to every device")
            cpu0, wall0 = sum(cpu_seconds(p.pid) for p in procs), time.monotonic()
            slot_threads0 = sum(cpu_seconds(p.pid, p.pid) for p in procs)
            own0, (idle0, ticks0) = time.process_time(), host_idle(edges_cores)
            # every slot played and answered, or 15 s past the last slot's period
            deadline = max(d.start for d in devices) + \
                (len(recording.summaries) + 7.5) * recording.slot_s
            while time.monotonic() < deadline and not all(
                    d.done and not d.uploads and len(d.stats) >= len(recording.summaries)
                    for d in devices):
                t = time.monotonic()
                for d in devices:
                    d.tick(t)
                # asleep until the next send is due or a message comes: each of rclpy's
                # spins builds a wait set of every device's topics, and spinning every few
                # milliseconds cost the emulator a third of a core at 24 devices — CPU the
                # edges share with it here, a real fleet's devices would not
                due = min(d.next_due() for d in devices) - time.monotonic()
                ros.spin_once(min(max(due, 0.0), SPIN_AT_MOST_S))
            cpu = sum(cpu_seconds(p.pid) for p in procs) - cpu0
            slot_threads = sum(cpu_seconds(p.pid, p.pid) for p in procs) - slot_threads0
            wall = time.monotonic() - wall0
            own, (idle, ticks) = time.process_time() - own0, host_idle(edges_cores)
        log = "".join(dom.stop(p)[2] for p in procs)
    stats = [s for d in devices for s in d.stats.values()]
    expected = n * len(recording.summaries)
    late = sum(1 for s in stats if s.slot_latency_ms > recording.slot_s * 1000)
    slots = [{"device": d.name, "slot": k, "latency_ms": s.slot_latency_ms,
              "compute_ms": s.slot_processing_ms, "restored": s.restored_keyframes,
              "uploads": s.uploads, "loops_closed": s.loops_closed,
              "lost_share": s.lost_share}
             for d in devices for k, s in sorted(d.stats.items())]
    compute = [s.slot_processing_ms for s in stats]
    latency = [s.slot_latency_ms for s in stats]
    return {"devices": n, "edges": len(served), "pools": pools,
            "network": "hosts" if hosts else "loopback", "device_slots": expected,
            "edge_cores": " ".join(format_cpu_list(c) for c in edge_cores),
            "answered": len(stats),
            "compute_ms_median": float(np.median(compute)) if compute else math.nan,
            "compute_ms_p95": float(np.percentile(compute, 95)) if compute else math.nan,
            "latency_ms_median": float(np.median(latency)) if latency else math.nan,
            "latency_ms_p95": float(np.percentile(latency, 95)) if latency else math.nan,
            "missed_share": (late + expected - len(stats)) / expected,
            "stagger_slots": stagger, "checkpoint_every": checkpoint_every,
            "loop_worker_niceness": -1 if niceness is None else niceness,
            "loop_worker_share": math.nan if share is None else share,
            "loop_worker_yields": "" if yields is None else ("on" if yields else "off"),
            "loops_across_devices": "" if across is None else ("on" if across else "off"),
            "lend_in_view": "" if in_view is None else ("on" if in_view else "off"),
            "lent_unseen_slots": -1 if unseen is None else unseen,
            "checkpoint_in_background": "" if background is None or not checkpoint_every
            else ("on" if background else "off"),
            # loops the edges closed over the run (each device's MapStats counts its own)
            "loops_closed": sum(max((s.loops_closed for s in d.stats.values()), default=0)
                                for d in devices),
            "edge_cpu_share": cpu / wall,
            # the edges' CPU for each device-slot they answered (ms of a core): what a
            # device-slot costs, against the host's cores over devices × slots a second
            "edge_cpu_ms_per_answered": 1000.0 * cpu / max(len(stats), 1),
            # how busy the edges' slot threads (their main threads, which serve every device)
            # were, a share of the run's wall time each
            "slot_thread_busy": slot_threads / (wall * len(procs)),
            # the emulated devices' own (this process: replay and DDS), in cores; and the
            # share of the host's cores nothing used: where none is left the host's CPU is
            # the limit, where some is the edges' own serial work is
            "devices_cpu_share": own / wall,
            "host_idle_share": (idle - idle0) / max(ticks - ticks0, 1),
            "missing_keyframes": sum(d.missing for d in devices),
            # the share of the replayed frames the edge finds lost on its map (the planned
            # slots' mean): a recording made by an edge that named its points otherwise
            # reports point ids this edge lacks, and its frames count as lost
            "lost_share": float(np.mean([s.lost_share for s in stats])) if stats else math.nan,
            "compute_budget": compute_budget, "trimmed": log.count("compute: slot work takes"),
            "merge_maps": merge_maps, "places": places, "emulator_executor": executor,
            "edge_params": "; ".join(extra),
            # each device moved into another's place logs it once, at its next slot end
            "merged": len(MOVED_LINE.findall(log)),
            "restored_a_slot": float(np.mean([s.restored_keyframes for s in stats]))
            if stats else math.nan,
            **by_sharing(slots, names, places, recording.slot_s, len(recording.summaries))}, slots


_Value = TypeVar("_Value", bool, int, float)


def values_to_compare(parser: argparse.ArgumentParser, option: str, text: str,
                      kind: Callable[[str], _Value], low: _Value, high: _Value, unit: str
                      ) -> list[_Value | None]:
    """An edge parameter's values a comma-separated option compares, each from ``low`` to
    ``high`` (a clear error otherwise); [None] when the option is not given: the edge's
    default."""
    if not text:
        return [None]
    try:
        values: list[_Value | None] = [kind(v) for v in text.split(",")]
    except ValueError:
        parser.error(f"{option}: {unit}, comma-separated, not {text!r}")
    if any(v is None or not low <= v <= high for v in values):
        parser.error(f"{option}: {unit} from {low:g} to {high:g}, not {text!r}")
    return values


def on_or_off(text: str) -> bool:
    """A switch option's value: on (True) or off (False); ValueError otherwise."""
    switch = {"on": True, "off": False}
    if text not in switch:
        raise ValueError(text)
    return switch[text]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", default="1,2,4,8,12,16", help="fleet sizes, comma-separated")
    parser.add_argument("--recording", type=Path, default=None,
                        help="a `twinslam launch --record` folder (default: one is made)")
    parser.add_argument("--policy", default="lff", help="the edge's policy (lff: the recording's)")
    parser.add_argument("--csv", type=Path, default=None, help="also write the table here")
    parser.add_argument("--slots-csv", type=Path, default=None,
                        help="write every device-slot here (its latency, the edge's compute, "
                             "the keyframes it restored and uploaded, loops closed): where in "
                             "the walk an edge falls behind")
    parser.add_argument("--edges", default="1",
                        help="edge processes the devices are split among, comma-separated "
                             "counts to compare (default 1)")
    parser.add_argument("--pools", default="one",
                        help="the edges' math thread pools: one (the nodes' default) or cores "
                             "(a thread a core, as before); comma-separated to compare")
    parser.add_argument("--compute-budget", type=float, default=0.0,
                        help="the edge's compute_budget (a share of one core; 0: none)")
    parser.add_argument("--merge-maps", default="off",
                        help="off, on, or off,on to compare: the edges merge the maps of their "
                             "devices (all of which replay one walk, so share one place, "
                             "unless --places)")
    parser.add_argument("--places", type=int, default=1,
                        help="places the fleet walks: device k replays the walk as place "
                             "k mod PLACES, its descriptors XORed with a mask of the place's "
                             "own, related to no other place's")
    parser.add_argument("--slots-plot", type=Path, default=None,
                        help="draw every setting's device-slots along the walk here (PNG): "
                             "the latency across devices against the slot period, the edge's "
                             "compute and the keyframes restored")
    parser.add_argument("--collector-log", action="store_true",
                        help="time every garbage collection in the edge processes "
                             "(bench/collector_watch) and report each setting's full "
                             "collections, start-up's included: how many, the longest, "
                             "their total")
    parser.add_argument("--stagger", type=float, default=1.0,
                        help="slot periods the devices' starts are spread over (default 1: a "
                             "period, every device at the same place of the walk, their "
                             "revisits together); more puts each at a place of the walk of "
                             "its own, as devices that joined at different times")
    parser.add_argument("--checkpoint-every", type=int, default=0, metavar="SLOTS",
                        help="the edges checkpoint every device's map every SLOTS slots (the "
                             "checkpoint and checkpoint_every parameters: what a standby edge "
                             "takes a device over from, and a restarted edge resumes from); "
                             "default 0: none")
    parser.add_argument("--loop-worker-niceness", default="", metavar="STEPS",
                        help="the edges' loop_worker_niceness (Linux nice steps their loop "
                             "closer's worker runs below the slots; 0: the same priority), "
                             "comma-separated to compare; default: the edge's")
    parser.add_argument("--loop-worker-share", default="", metavar="SHARE",
                        help="the edges' loop_worker_share (the most of a core their loop "
                             "closer's worker takes; 1: all it can get), comma-separated to "
                             "compare; default: the edge's")
    parser.add_argument("--loop-worker-yields", default="", metavar="on|off",
                        help="the edges' loop_worker_yields (their loop closer's worker waits "
                             "while the slots' work runs), on, off or both comma-separated "
                             "to compare; default: the edge's")
    parser.add_argument("--checkpoints-in-background", default="", metavar="on|off",
                        help="with --checkpoint-every, the edges' checkpoint_in_background "
                             "(the files written on a thread of their own, or on the slot "
                             "thread before the map update goes out), on, off or both "
                             "comma-separated to compare; default: the edge's")
    parser.add_argument("--loops-across", default="", metavar="on|off",
                        help="with --merge-maps on, the edges' loops_across_devices (a merged "
                             "map's loops also close with the other devices' keyframes), on, "
                             "off or both comma-separated to compare; default: the edge's")
    parser.add_argument("--lend-in-view", default="", metavar="on|off",
                        help="with --merge-maps on, the edges' lend_in_view (a merged map "
                             "adopts another device's keyframe once its device heads where it "
                             "sees it, or as soon as it was made), on, off or both "
                             "comma-separated to compare; default: the edge's")
    parser.add_argument("--unseen-slots", default="", metavar="SLOTS",
                        help="with --merge-maps on, the edges' lent_unseen_slots (a lent "
                             "keyframe's copy its device has neither held nor seen for that "
                             "many slots goes back to its lender; 0: copies stay), comma-"
                             "separated to compare; default: the edge's")
    parser.add_argument("--emulator-executor", default="events", metavar="events|single",
                        help="the rclpy executor the emulated devices spin on: events (the "
                             "nodes' EventsExecutor) or single (SingleThreadedExecutor, which "
                             "builds a wait set of every device's topics each turn: the "
                             "bench's default until 2026-12-05); comma-separated to compare")
    parser.add_argument("--edge-param", action="append", default=[], metavar="NAME:=VALUE",
                        help="one more ROS parameter for every edge process, as `-p` takes it "
                             "(repeat for several; e.g. loop_closing:=false: what the fleet "
                             "costs without the loop closer's worker); recorded in the CSV's "
                             "edge_params")
    parser.add_argument("--hosts", action="store_true",
                        help="each edge process on an edge host of its own and the devices on "
                             "a device host (network namespaces on one switch; needs root) "
                             "instead of one loopback domain")
    parser.add_argument("--edge-cores", default="", metavar='"LIST LIST …"',
                        help="hold edge process k to the k-th CPU list (taskset's form: 0-1, "
                             "2,3), cycled: \"0-1 0-1 2-3 2-3\" with --edges 4 is two "
                             "2-core edge hosts of two processes each, measured in one run on "
                             "a machine with cores to spare (default: the edges run on any "
                             "core); the idle column is then their cores'")
    parser.add_argument("--device-cores", default="", metavar="LIST",
                        help="hold the emulated devices (this process) to these cores, apart "
                             "from the edges' (default: any core)")
    args = parser.parse_args()
    try:
        edge_cores = [usable(parse_cpu_list(text)) for text in args.edge_cores.split()]
        device_cores = usable(parse_cpu_list(args.device_cores)) \
            if args.device_cores.strip() else None
    except CpuSetError as exc:
        parser.error(f"--edge-cores / --device-cores: {exc}")
    if device_cores is not None and device_cores & frozenset().union(*edge_cores):
        parser.error("--device-cores: the devices' cores overlap the edges' "
                     f"({format_cpu_list(device_cores & frozenset().union(*edge_cores))})")
    if args.stagger < 0:
        parser.error(f"--stagger: slot periods, 0 or more, not {args.stagger:g}")
    if args.checkpoint_every < 0:
        parser.error(f"--checkpoint-every: slots, 0 or more, not {args.checkpoint_every}")
    if args.places < 1:
        parser.error(f"--places: 1 or more, not {args.places}")
    nicenesses = values_to_compare(parser, "--loop-worker-niceness",
                                   args.loop_worker_niceness, int, 0, 19, "steps")
    shares = values_to_compare(parser, "--loop-worker-share", args.loop_worker_share, float,
                               0.05, 1.0, "shares of a core")
    yielding = values_to_compare(parser, "--loop-worker-yields", args.loop_worker_yields,
                                 on_or_off, False, True, "on or off")
    backgrounds = values_to_compare(parser, "--checkpoints-in-background",
                                    args.checkpoints_in_background, on_or_off, False, True,
                                    "on or off")
    acrosses = values_to_compare(parser, "--loops-across", args.loops_across, on_or_off,
                                 False, True, "on or off")
    in_views = values_to_compare(parser, "--lend-in-view", args.lend_in_view, on_or_off,
                                 False, True, "on or off")
    unseens = values_to_compare(parser, "--unseen-slots", args.unseen_slots, int, 0, 100_000,
                                "slots")
    for extra in args.edge_param:
        if not EDGE_PARAM.fullmatch(extra):
            parser.error(f"--edge-param: NAME:=VALUE (a parameter name, ':=', a value), not "
                         f"{extra!r}")
        name = extra.split(":=", 1)[0]
        if name in BENCH_SETS:
            parser.error(f"--edge-param {name}: the bench sets it for every run"
                         + (f" (its {BENCH_SETS[name]})" if BENCH_SETS[name] else ""))
    executors = args.emulator_executor.split(",")
    if not set(executors) <= set(EXECUTORS):
        parser.error(f"--emulator-executor: events, single or both, not "
                     f"{args.emulator_executor!r}")
    why_not = unavailable_reason() if args.hosts else None
    if why_not is not None:
        raise SystemExit(f"--hosts: network namespaces cannot be made here: {why_not}")
    with tempfile.TemporaryDirectory(prefix="twinslam-scaling-") as tmp:
        folder = args.recording
        if folder is None:
            folder = Path(tmp) / "run"
            record(folder)
        recording = Recording.read(folder)
    checkpoints = (f"maps checkpointed every {args.checkpoint_every} slots; "
                   if args.checkpoint_every else "")
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}; {len(recording.summaries)} slots a device, "
          f"{len(recording.keyframes)} keyframes recorded; policy {args.policy}; slot period "
          f"{recording.slot_s:.3g} s (the recording's); compute budget "
          f"{args.compute_budget:g} of a core; the devices' starts spread over "
          f"{args.stagger:g} slot periods; {args.places} place(s); "
          f"{checkpoints}"
          f"{'edge and device hosts (network namespaces)' if args.hosts else 'loopback'}"
          f"{'; every edge with ' + ' '.join(args.edge_param) if args.edge_param else ''}"
          f"{'; edges held to cores ' + args.edge_cores if edge_cores else ''}"
          f"{'; devices to ' + format_cpu_list(device_cores) if device_cores else ''}",
          flush=True)
    # the edges start where this process could run, unless held to cores of their own
    everywhere = frozenset(os.sched_getaffinity(0))
    if device_cores is not None:
        os.sched_setaffinity(0, device_cores)
    rows = []
    merging = {"off": False, "on": True}
    unknown = [m for m in args.merge_maps.split(",") if m not in merging]
    if unknown:
        raise SystemExit(f"--merge-maps: off, on or off,on, not {args.merge_maps!r}")
    header = (f"{'pools':>5} {'merge':>5} {'edges':>5} {'devices':>7} {'answered':>9} "
              f"{'edge ms/slot':>12} {'p95':>6} "
              f"{'latency ms':>10} {'p95':>6} {'missed':>7} {'edge CPU':>8} {'ms/answer':>9} "
              f"{'slot thr':>8} "
              f"{'devices CPU':>11} {'idle':>5} {'merged':>6} {'lost':>5} {'loops':>5} "
              f"{'nice':>4} {'share':>5} {'yield':>5} {'ckpt bg':>7} {'across':>6} "
              f"{'view':>4} {'unseen':>6} {'emulator':>8}")
    print(header, flush=True)
    settings = [(pools, merge, int(edges), int(n), nice, share, yields, background, across,
                 in_view, unseen, executor)
                for executor in executors
                for pools in args.pools.split(",")
                for merge in args.merge_maps.split(",")
                for edges in args.edges.split(",") for n in args.devices.split(",")
                for nice in nicenesses for share in shares for yields in yielding
                for background in backgrounds for across in acrosses
                for in_view in in_views for unseen in unseens]
    every_slot = []
    for (pools, merge, edges, n, nice, share, yields, background, across, in_view,
         unseen, executor) in settings:
        with collector_log(args.collector_log) as collections:
            row, slots = measure(n, recording, args.policy, args.compute_budget, edges, pools,
                                 args.hosts, merging[merge], args.stagger,
                                 args.checkpoint_every, nice, share, yields, background,
                                 across, in_view, unseen, args.places, executor,
                                 tuple(args.edge_param), edge_cores,
                                 everywhere if device_cores is not None else None)
            full = [c for c in collections() if c[0] == 2]
        if row["devices_sharing"] and row["devices_alone"]:
            print(f"      {row['devices_sharing']} devices sharing a place: "
                  f"{row['missed_share_sharing']:.1%} late, "
                  f"{row['compute_ms_median_sharing']:.0f} ms a slot (median), "
                  f"{row['restored_a_slot_sharing']:.2f} restored a slot, "
                  f"{row['lost_share_sharing']:.1%} lost; {row['devices_alone']} alone in "
                  f"theirs: {row['missed_share_alone']:.1%}, "
                  f"{row['compute_ms_median_alone']:.0f} ms, "
                  f"{row['restored_a_slot_alone']:.2f}, {row['lost_share_alone']:.1%}",
                  flush=True)
        if args.collector_log:
            row.update(full_collections=len(full),
                       full_collection_ms_max=max((c[1] for c in full), default=0.0),
                       full_collection_ms_total=sum(c[1] for c in full))
            print(f"      the edges' full collections: {len(full)}, the longest "
                  f"{row['full_collection_ms_max']:.0f} ms, "
                  f"{row['full_collection_ms_total']:.0f} ms in all", flush=True)
        rows.append(row)
        every_slot += [{"pools": pools, "merge_maps": merge, "edges": row["edges"],
                        "devices": n, "loop_worker_niceness": row["loop_worker_niceness"],
                        "loop_worker_share": row["loop_worker_share"],
                        "loop_worker_yields": row["loop_worker_yields"],
                        "checkpoint_in_background": row["checkpoint_in_background"],
                        "loops_across_devices": row["loops_across_devices"],
                        "lend_in_view": row["lend_in_view"],
                        "lent_unseen_slots": row["lent_unseen_slots"],
                        "emulator_executor": executor, **slot}
                       for slot in slots]
        print(f"{pools:>5} {merge:>5} {row['edges']:>5} {n:>7} "
              f"{row['answered']:>4.0f}/{row['device_slots']:<4.0f} "
              f"{row['compute_ms_median']:>12.0f} {row['compute_ms_p95']:>6.0f} "
              f"{row['latency_ms_median']:>10.0f} {row['latency_ms_p95']:>6.0f} "
              f"{row['missed_share']:>7.1%} {row['edge_cpu_share']:>8.0%} "
              f"{row['edge_cpu_ms_per_answered']:>9.0f} {row['slot_thread_busy']:>8.0%} "
              f"{row['devices_cpu_share']:>11.0%} {row['host_idle_share']:>5.0%} "
              f"{row['merged']:>6} {row['lost_share']:>5.1%} {row['loops_closed']:>5} "
              f"{'edge' if nice is None else nice:>4} "
              f"{'edge' if share is None else f'{share:g}':>5} "
              f"{row['loop_worker_yields'] or 'edge':>5} "
              f"{row['checkpoint_in_background'] or 'edge':>7} "
              f"{row['loops_across_devices'] or 'edge':>6} "
              f"{row['lend_in_view'] or 'edge':>4} "
              f"{'edge' if unseen is None else unseen:>6} {executor:>8}", flush=True)
    if args.csv:
        write_dict_rows(args.csv, rows)
        print(f"wrote {args.csv}")
    if args.slots_csv:
        write_dict_rows(args.slots_csv, every_slot)
        print(f"wrote {args.slots_csv}")
    if args.slots_plot:
        plot_slots(every_slot, recording.slot_s, args.slots_plot)
        print(f"wrote {args.slots_plot}")


@contextlib.contextmanager
def collector_log(wanted: bool) -> Iterator[Callable[[], list[tuple[int, float]]]]:
    """While it is open, the edge processes started time their garbage collections
    (``bench/collector_watch`` on their ``PYTHONPATH``); yields a reader of every collection
    logged: (generation, milliseconds)."""
    if not wanted:
        yield lambda: []
        return
    hook = str(REPO / "bench" / "collector_watch")
    with tempfile.TemporaryDirectory(prefix="twinslam-collector-") as folder, environment(
            {"TWINSLAM_COLLECTOR_LOG": folder,
             "PYTHONPATH": os.pathsep.join(filter(None, [hook, os.environ.get("PYTHONPATH")]))}):

        def read() -> list[tuple[int, float]]:
            return [(int(g), float(ms)) for log in Path(folder).glob("*.txt")
                    for _, g, ms, _ in (line.split() for line in log.read_text().splitlines())]

        yield read


def plot_slots(slots: list[dict[str, Any]], slot_s: float, path: Path) -> None:
    """Each setting's device-slots along the walk: the latency from summaries to map (median
    and worst across devices) against the slot period, the edge's compute a device-slot
    (median) and the keyframes the edge restored (all devices) — where an edge falls behind
    and what it was doing then."""
    plt = pyplot()
    settings = sorted({(s["pools"], s["merge_maps"], s["edges"], s["devices"]) for s in slots})
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for setting in settings:
        mine = [s for s in slots
                if (s["pools"], s["merge_maps"], s["edges"], s["devices"]) == setting]
        walk = sorted({s["slot"] for s in mine})
        by_slot = {k: [s for s in mine if s["slot"] == k] for k in walk}
        label = f"{setting[3]} devices, {setting[2]} edge{'s' * (setting[2] > 1)}" + \
            (", shared place" if setting[1] == "on" else "")
        latency = [np.median([s["latency_ms"] for s in by_slot[k]]) / 1e3 for k in walk]
        worst = [max(s["latency_ms"] for s in by_slot[k]) / 1e3 for k in walk]
        line, = axes[0].plot(walk, latency, marker="o", ms=3, label=f"{label}: median")
        axes[0].plot(walk, worst, ls="--", color=line.get_color(), label=f"{label}: worst")
        axes[1].plot(walk, [np.median([s["compute_ms"] for s in by_slot[k]]) for k in walk],
                     color=line.get_color(), marker="o", ms=3, label=f"{label}: compute")
        axes[1].bar(walk, [sum(s["restored"] for s in by_slot[k]) for k in walk], alpha=0.3,
                    color=line.get_color(), label=f"{label}: keyframes restored (all)")
    axes[0].axhline(slot_s, color="k", lw=0.8, label="the slot period (later is late)")
    axes[0].set_ylabel("summaries → map (s)")
    axes[0].legend(fontsize=7)
    axes[1].set_ylabel("edge ms a device-slot / restored")
    axes[1].set_xlabel("slot of the recorded walk")
    axes[1].xaxis.get_major_locator().set_params(integer=True)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
