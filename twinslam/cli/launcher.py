"""``twinslam launch``: the pipeline without a ROS installation — player, device, edge (and the
twin) as separate rclpy processes on one ROS domain with one parameter file, a live status line
per slot, and a clean stop (SIGTERM, then SIGKILL) of every process at the end or on Ctrl-C.

A monitor node (its own rclpy context) in this process listens to the run's topics and ends with a
:class:`RunReport`: mean υ (and the share of lost next-slot frames), ATE of ``/device/pose``
against ``/camera/ground_truth_pose`` (evo, SE(3)-aligned), frames and bytes uploaded, the
throughput achieved, frames the device could not track, and the edge's milliseconds per slot.
"""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
import yaml
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import Image
from twinslam_msgs.msg import (
    FrameSummaries,
    MapStats,
    MapUpdate,
    RateLatent,
    UplinkThroughput,
    UploadRequest,
)

from msg_schemas import qos, topics
from msg_schemas.headers import stamp_key, stamp_seconds
from msg_schemas.poses import pose_matrix
from twinslam.cli.scenarios import SCENARIOS, Scenario
from twinslam.common import table1
from twinslam.node_hosts.fastdds import REPO_ROOT
from twinslam.node_hosts.loopback import ProcessDomain
from twinslam.node_hosts.session import RosSession
from twinslam.slam.map_update import MapSnapshot, read_map_update
from twinslam.slam.tracking_quality import (
    FrameFlags,
    TrackingEvents,
    absolute_trajectory_error,
    relative_pose_error,
    tracking_events,
)

REPO = REPO_ROOT
#: the module each node's process runs (``python -m``), as setup.py's console scripts do
NODE_MODULES = {"sequence_player": "twinslam.sequence_player.node",
                "device_tracker": "device_tracker.node", "edge_mapper": "edge_mapper.node",
                "udt_node": "udt_node.node"}
#: where each node runs when the domain has hosts (twinslam.node_hosts.netns): the camera is the
#: device's
NODE_HOSTS = {"sequence_player": "device", "device_tracker": "device", "edge_mapper": "edge",
              "udt_node": "twin"}
DEFAULT_PARAMS = REPO / "config" / "twinslam.yaml"


@dataclass
class RunRecord:
    """Everything the monitor heard, by slot (messages as received)."""

    summaries: dict[int, Any] = field(default_factory=dict)
    requests: dict[int, Any] = field(default_factory=dict)
    stats: dict[int, Any] = field(default_factory=dict)
    throughput: dict[int, Any] = field(default_factory=dict)
    maps: dict[int, MapSnapshot] = field(default_factory=dict)   #: last map update per slot
    poses: dict[int, np.ndarray] = field(default_factory=dict)        #: stamp ns → pose
    ground_truth: dict[int, np.ndarray] = field(default_factory=dict)
    latents: dict[int, Any] = field(default_factory=dict)    #: the twin's, by slot
    images_received: int = 0        #: /camera/image_raw samples, when the monitor watches them


@dataclass
class RunReport:
    policy: str
    slots: int
    mean_uncertainty: float          #: mean υ over slots, a lost next-slot frame scoring 0
    lost_ratio: float                #: mean share of next-slot frames MapStats calls lost
    tracked_uncertainty: float       #: mean υ over slots, tracked next-slot frames only
    ate_m: float                     #: NaN without ground truth
    rpe_m: float                     #: over 1 s (30 frames); NaN without ground truth
    frames_uploaded: int
    bytes_uploaded: int
    achieved_mbps: float             #: mean over slots with uploads
    untracked_frames: int
    tracking_failures: int           #: tracked → untracked transitions
    relocalisations: int             #: frames tracked again by relocalisation
    recover_s: float                 #: mean seconds from a loss to tracking again (NaN: none)
    edge_ms_median: float
    seconds: float
    #: which policy decided how many slots (``UploadRequest.policy``), e.g. "amm-regime:28
    #: adapt:2" — a learned policy's fallback shows here
    decided_by: str = ""
    #: camera frames missing from the device's complete slots (dropped or skipped): a device
    #: that fell behind the camera (an overloaded machine) shows here
    frames_dropped: int = 0

    ROW = ("{label:<14} {mean_uncertainty:>10.1f} {lost_ratio:>6.1%} "
           "{tracked_uncertainty:>10.1f} {ate_m:>7.3f} "
           "{rpe_m:>7.3f} {frames_uploaded:>7d} {mbytes:>7.1f} {achieved_mbps:>7.1f} "
           "{untracked_frames:>6d} {tracking_failures:>5d} {relocalisations:>6d} "
           "{recover_s:>7.2f} {edge_ms_median:>7.0f}")
    HEADER = (f"{'policy':<14} {'mean υ':>10} {'lost':>6} {'υ tracked':>10} {'ATE m':>7} "
              f"{'RPE m':>7} "
              f"{'uploads':>7} {'MB':>7} {'Mbit/s':>7} {'untrk':>6} {'fails':>5} "
              f"{'reloc':>6} {'recov s':>7} {'edge ms':>7}")

    @property
    def label(self) -> str:
        """The policy as the table shows it: a learned one by its checkpoint's file name."""
        kind, sep, path = self.policy.partition(":")
        return f"{kind}:{Path(path).stem}" if sep else self.policy

    def row(self) -> str:
        return self.ROW.format(mbytes=self.bytes_uploaded / 1e6, label=self.label,
                               **self.__dict__)


class PipelineMonitor:
    """Subscribes to the run's topics with ``node`` and keeps what it hears."""

    def __init__(self, node: Node, on_stats: Callable[[Any, RunRecord], None] | None = None,
                 watch_images: bool = False) -> None:
        self.record = RunRecord()
        self._on_stats = on_stats
        r = self.record
        sub = node.create_subscription
        sub(FrameSummaries, topics.FRAME_SUMMARIES,
            lambda m: r.summaries.__setitem__(int(m.slot), m), qos.PROTOCOL)
        #: its publisher count says whether the edge is up (it publishes after warming up)
        self.requests = sub(UploadRequest, topics.UPLOAD_REQUEST,
                            lambda m: r.requests.__setitem__(int(m.slot), m), qos.PROTOCOL)
        sub(UplinkThroughput, topics.UPLINK_THROUGHPUT,
            lambda m: r.throughput.__setitem__(int(m.slot), m), qos.PROTOCOL)
        #: its publisher count says whether the twin is up (it publishes once its model is in)
        self.latents = sub(RateLatent, topics.RATE_LATENT,
                           lambda m: r.latents.__setitem__(int(m.slot), m), qos.PROTOCOL)
        sub(MapStats, topics.MAP_STATS, self._stats, qos.PROTOCOL)
        # every map the edge sends (not only the latest a late joiner gets)
        map_qos = rclpy.qos.QoSProfile(depth=100, durability=qos.MAP.durability,
                                       reliability=qos.MAP.reliability)
        sub(MapUpdate, topics.MAP_UPDATE,
            lambda m: r.maps.__setitem__(int(m.slot), read_map_update(m)), map_qos)
        sub(PoseStamped, topics.DEVICE_POSE,
            lambda m: r.poses.__setitem__(stamp_key(m.header), pose_matrix(m.pose)),
            qos.PROTOCOL)
        sub(PoseStamped, topics.GROUND_TRUTH_POSE,
            lambda m: r.ground_truth.__setitem__(stamp_key(m.header), pose_matrix(m.pose)),
            qos.CAMERA)
        if watch_images:     # a viewer's subscription: best effort, undecoded, only counted
            sub(Image, topics.CAMERA_IMAGE, self._image, qos.SENSOR_DATA, raw=True)

    def _image(self, _data: bytes) -> None:
        self.record.images_received += 1

    def _stats(self, msg: Any) -> None:
        self.record.stats[int(msg.slot)] = msg
        if self._on_stats:
            self._on_stats(msg, self.record)


def status_line(msg: Any, record: RunRecord) -> str:
    """One slot as a line: rate, decision, map, uncertainty, timing."""
    slot = int(msg.slot)
    req = record.requests.get(slot)
    summ = record.summaries.get(slot)
    rate = f"{summ.rate_mbps:4.0f}" if summ is not None else "   ?"
    ups = len(req.upload_frame_ids) if req is not None else 0
    ev = len(req.evict_frame_ids) if req is not None else 0
    nu = msg.mean_next_uncertainty
    return (f"[{msg.policy}] slot {slot:3d} | d_k {rate} Mbit/s | U {ups} C {ev} | map "
            f"{msg.map_size:2d} kf {msg.map_points:6d} pts | u {msg.uncertainty:9.1f} | υ "
            f"{nu:9.1f} lost {msg.lost_frame_ratio:4.0%} tracked "
            f"{msg.tracked_next_uncertainty:9.1f} | GTSAM {msg.optimisation_ms:4.0f} ms,"
            f" slot {msg.slot_processing_ms:4.0f} ms")


def record_events(record: RunRecord) -> TrackingEvents:
    """The device's tracking failures and relocalisations, from its frame summaries."""
    return tracking_events(FrameFlags(stamp_seconds(f), bool(f.tracked), bool(f.relocalised))
                           for s in record.summaries.values() for f in s.frames)


def _finite_mean(values: Iterable[float]) -> float:
    """Mean of the finite values (NaN: the edge did not know, or nothing was tracked)."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def report(policy: str, record: RunRecord, seconds: float, slot_frames: int) -> RunReport:
    """What the run measured; ``slot_frames``: the device's F, to count dropped frames."""
    stats = [record.stats[s] for s in sorted(record.stats)]
    scored = stats[1:]         # slot 0 plans against an empty map: every policy loses it all
    tps = [t for t in record.throughput.values() if t.frames_sent]
    events = record_events(record)
    return RunReport(policy, len(stats), _finite_mean(s.mean_next_uncertainty for s in scored),
                     float(np.mean([s.lost_frame_ratio for s in scored])) if scored else 0.0,
                     _finite_mean(s.tracked_next_uncertainty for s in scored),
                     absolute_trajectory_error(record.poses, record.ground_truth),
                     relative_pose_error(record.poses, record.ground_truth),
                     sum(int(t.frames_sent) for t in record.throughput.values()),
                     sum(int(t.bytes_sent) for t in record.throughput.values()),
                     float(np.mean([t.achieved_mbps for t in tps])) if tps else 0.0,
                     events.untracked, events.failures, events.relocalisations,
                     events.mean_recover_s,
                     float(np.median([s.slot_processing_ms for s in stats])) if stats
                     else math.nan, seconds, deciders(record),
                     dropped_frames(record, slot_frames))


def dropped_frames(record: RunRecord, slot_frames: int) -> int:
    """Frames missing from every slot but the last (which the run may end inside)."""
    slots = sorted(record.summaries)[:-1]
    return sum(max(0, slot_frames - len(record.summaries[s].frames)) for s in slots)


def deciders(record: RunRecord) -> str:
    """"name:slots" for each policy that decided a slot of the run, most slots first."""
    counts: dict[str, int] = {}
    for request in record.requests.values():
        counts[str(request.policy)] = counts.get(str(request.policy), 0) + 1
    return " ".join(f"{name}:{n}" for name, n in sorted(counts.items(), key=lambda x: -x[1]))


@dataclass
class LaunchConfig:
    sequence: str = "synthetic"
    policy: str = "adapt"
    frames: int = 600                #: played from frame ``start`` on; -1: all
    rate: float = 1.0                #: × the recorded frame rate
    params_file: Path = DEFAULT_PARAMS
    checkpoint: Path | None = None
    with_twin: bool = False
    watch_images: bool = False       #: the monitor also views /camera/image_raw (best effort)
    extra: dict[str, list[str]] = field(default_factory=dict)   #: node → more "-p k:=v"
    timeout_s: float = 600.0
    scenario: Scenario = SCENARIOS["forward"]   #: order, covered-lens bursts, uplink range
    start: int = 0                   #: the sequence's first frame played


class Launcher:
    """Starts the nodes on ``domain`` and watches them; ``run`` blocks until the sequence is
    played and the edge has answered its last full slot."""

    NODES = ("edge_mapper", "udt_node", "device_tracker", "sequence_player")

    def __init__(self, domain: ProcessDomain, config: LaunchConfig,
                 echo: Callable[[str], None] | None = print) -> None:
        self.domain, self.config, self.echo = domain, config, echo
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self.logs: dict[str, str] = {}         #: each node's stderr (its log), after stop
        self._killed: set[int] = set()         #: pids killed on purpose (``kill``)
        #: what the monitor heard, by slot: filled while ``run`` plays, kept afterwards
        self.record: RunRecord | None = None

    def node_args(self, name: str) -> list[str]:
        c = self.config
        args = ["-m", NODE_MODULES[name], "--ros-args", "--params-file", str(c.params_file)]
        params = {"edge_mapper": [f"policy:={c.policy}"]
                  + ([f"checkpoint:={c.checkpoint}"] if c.checkpoint else []),
                  "sequence_player": [f"sequence:={c.sequence}", f"rate:={c.rate}",
                                      f"start:={c.start}",
                                      f"end:={c.start + c.frames if c.frames > 0 else -1}",
                                      # the device, and the monitor when it views images
                                      f"wait_for_subscribers:={1 + c.watch_images}"]
                  }.get(name, [])
        params += c.scenario.node_params(c.frames, self._device_param(
            "frame_rate_hz", table1.FRAME_RATE_HZ)).get(name, []) + c.extra.get(name, [])
        if name == "device_tracker" and c.rate != 1.0:
            # slots are cut by stamps: replayed faster, the camera's frames come faster
            nominal = self._device_param("frame_rate_hz", table1.FRAME_RATE_HZ)
            params.append(f"frame_rate_hz:={nominal * c.rate!r}")
        for p in params:
            args += ["-p", p]
        return args

    def start(self, name: str) -> subprocess.Popen[str]:
        proc = self.domain.spawn(self.node_args(name), host=NODE_HOSTS[name])
        self.procs[name] = proc
        return proc

    def run(self, on_stats: Callable[[Any, RunRecord], None] | None = None) -> RunReport:
        """Play, watch, stop; ``on_stats(msg, record)`` runs on every ``MapStats`` (tests use
        it to inject faults mid-run)."""
        with self.domain.monitor_scope():
            return self._run(on_stats)

    def _run(self, on_stats: Callable[[Any, RunRecord], None] | None) -> RunReport:
        c = self.config
        session = RosSession("twinslam_monitor")
        try:
            def stats(msg: Any, record: RunRecord) -> None:
                if self.echo:
                    self.echo(status_line(msg, record))
                if on_stats:
                    on_stats(msg, record)

            monitor = PipelineMonitor(session.node, stats, c.watch_images)
            self.record = monitor.record
            started = time.monotonic()
            # the edge first, and the rest once it listens: summaries published before the
            # edge's reader matched would be lost (the device starts the slots with the player)
            edge = self.start("edge_mapper")
            if not session.spin_until(lambda: monitor.requests.get_publisher_count() > 0
                                       or edge.poll() is not None, min(120.0, c.timeout_s)):
                raise RuntimeError("edge_mapper did not come up within 120 s")
            if edge.poll() is not None:
                raise RuntimeError(f"edge_mapper exited with {edge.returncode} at start")
            if c.with_twin:
                # the twin before the camera: a twin-driven policy decides a slot with the
                # edge's fallback policy until the twin's first latent (loading torch and a
                # model takes seconds, more on a loaded machine)
                twin = self.start("udt_node")
                if not session.spin_until(lambda: monitor.latents.get_publisher_count() > 0
                                           or twin.poll() is not None, min(120.0, c.timeout_s)):
                    raise RuntimeError("udt_node did not come up within 120 s")
                if twin.poll() is not None:
                    _, _, err = self.domain.stop(self.procs.pop("udt_node"))
                    raise RuntimeError(f"udt_node exited with {twin.returncode} at start: "
                                       f"{err.strip()[-500:]}")
            for name in ("device_tracker", "sequence_player"):
                self.start(name)
            player = self.procs["sequence_player"]
            deadline = started + c.timeout_s
            session.spin_until(lambda: player.poll() is not None or self._failed(),
                                c.timeout_s)
            failed = self._failed()
            if failed:
                _, _, err = self.domain.stop(self.procs.pop(failed))
                raise RuntimeError(f"{failed} exited during the run: {err.strip()[-800:]}")
            if player.returncode not in (0, None):
                _, _, err = self.domain.stop(self.procs.pop("sequence_player"))
                raise RuntimeError(f"sequence_player exited with {player.returncode}: "
                                   f"{err.strip()[-500:]}")
            # the device's last summaries may still be in flight (a lossy link retransmits):
            # wait for every full slot of the frames played, or what arrived when unknown
            summaries = monitor.record.summaries
            expected = self._expected_slots()
            last = expected - 1 if expected else (max(summaries) if summaries else -1)
            session.spin_until(lambda: last in monitor.record.stats and all(
                s in monitor.record.throughput for s in monitor.record.requests),
                # at least 10 s even when a slow start (a fresh checkout compiles its kernels)
                # used up most of the run's timeout
                min(60.0, max(10.0, deadline - time.monotonic())))
            session.spin_until(lambda: False, 0.5)       # late poses and map updates
            return report(c.policy, monitor.record, time.monotonic() - started,
                          int(self._device_param("slot_frames", table1.SLOT_FRAMES)))
        finally:
            self.stop()
            session.close()

    def _expected_slots(self) -> int | None:
        """Full slots in the frames played (None when the whole sequence plays)."""
        if self.config.frames <= 0:
            return None
        played = self.config.scenario.played_frames(self.config.frames)
        return played // int(self._device_param("slot_frames", table1.SLOT_FRAMES))

    def _device_param(self, name: str, default: float) -> float:
        """A device parameter as the node will read it: ``extra`` over the parameter file
        over the node's default."""
        value = node_parameters(self.config.params_file, "device_tracker").get(name, default)
        for item in self.config.extra.get("device_tracker", []):
            key, _, given = item.partition(":=")
            if key == name:
                value = given
        return float(value)

    def kill(self, name: str) -> None:
        """SIGKILL a node on purpose (a fault injected mid-run): not a failure of the run."""
        proc = self.procs[name]
        proc.kill()
        proc.wait(timeout=10)
        self._killed.add(proc.pid)

    def _failed(self) -> str | None:
        """A node that exited with an error while the sequence plays (none: None)."""
        return next((name for name, proc in self.procs.items()
                     if name != "sequence_player" and proc.pid not in self._killed
                     and proc.poll() not in (None, 0)), None)

    def stop(self) -> dict[str, int]:
        codes = {}
        for name, proc in list(self.procs.items()):
            code, _, err = self.domain.stop(proc)
            codes[name] = code
            self.logs[name] = err
            if code not in (0, -15) and self.echo:
                self.echo(f"{name} exited with {code}: {err.strip()[-2000:]}")
        return codes


def node_parameters(params_file: Path, node: str) -> dict[str, Any]:
    """The ``ros__parameters`` a ROS 2 parameter file gives ``node`` (by its plain name or
    ``/**``), for the launcher's own bookkeeping; the nodes read the file themselves."""
    doc = yaml.safe_load(Path(params_file).read_text(encoding="utf-8")) or {}
    out: dict[str, Any] = {}
    for key in ("/**", node, f"/{node}"):
        out.update((doc.get(key) or {}).get("ros__parameters", {}))
    return out


def tc_uplink_params(alpha_mbit: float, **device: str) -> dict[str, list[str]]:
    """Node parameters for an uplink shaped by tc that carries real frames (each keyframe with
    its image): α, the frame's size in Mbit, the same on device and edge so that Theorem 1's
    |U_k| fits D_req; ``device`` adds device parameters (e.g. ``netem_delay_ms="2"``)."""
    alpha = f"alpha_mbit:={alpha_mbit:g}"
    return {"device_tracker": ["shaper:=tc", "upload_image:=true", alpha,
                               *(f"{k}:={v}" for k, v in device.items())],
            "edge_mapper": [alpha]}


def print_table(reports: list[RunReport], echo: Callable[[str], None] = print) -> None:
    echo(RunReport.HEADER)
    for r in reports:
        echo(r.row())
