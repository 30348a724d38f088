"""``twinslam launch``: the pipeline without a ROS installation — player, device, edge (and the
twin) as separate rclpy processes on one ROS domain with one parameter file, a live status line
per slot, and a clean stop (SIGTERM, then SIGKILL) of every process at the end or on Ctrl-C.

A monitor node (its own rclpy context) in this process listens to the run's topics and ends with a
:class:`RunReport`: mean υ (and the share of lost next-slot frames), ATE of ``/device/pose``
against ``/camera/ground_truth_pose`` (evo, SE(3)-aligned), frames and bytes uploaded, the
throughput achieved, frames the device could not track, and the edge's milliseconds per slot.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from twinslam.hosts.fastdds import REPO_ROOT
from twinslam.hosts.forked import ForkServers, NodeProcess
from twinslam.hosts.loopback import ProcessDomain
from twinslam.live.monitor import PipelineMonitor, status_line
from twinslam.live.node_fork_server import SWITCH, fork_servers
from twinslam.live.parameter_files import EVERY_NODE, any_namespace, node_parameters
from twinslam.live.playback_end import PlaybackEnd
from twinslam.live.report import RunReport, report
from twinslam.live.run_bag import RecordingOptions, RecordingSummary, RunRecorder
from twinslam.live.run_log import RunLog
from twinslam.live.scenarios import SCENARIOS, Scenario
from twinslam.node_runtime.middleware_teardown import ended_as_asked
from twinslam.node_runtime.session import RosSession
from twinslam.sequence_player.playback import played_device_slot
from twinslam.sequences.opening import AUTO

REPO = REPO_ROOT
#: seconds a run's end waits at most for the device's pose of the last frame played
LAST_POSE_WAIT_S = 5.0
#: seconds a run waits at most, once the player exited, for its answer to an end it asked for
#: (the answer was sent before the exit: only the monitor's spin has to take it)
END_ANSWER_WAIT_S = 10.0
#: the module each node's process runs (``python -m``), as setup.py's console scripts do
NODE_MODULES = {"sequence_player": "twinslam.sequence_player.node",
                "device_tracker": "device_tracker.node", "edge_mapper": "edge_mapper.node",
                "udt_node": "udt_node.node"}
#: where each node runs when the domain has hosts (twinslam.hosts.netns): the camera is the
#: device's
NODE_HOSTS = {"sequence_player": "device", "device_tracker": "device", "edge_mapper": "edge",
              "udt_node": "twin"}
#: the default device's parameter file (twinslam/slot_protocol/default_device.py)
DEFAULT_PARAMS = REPO / "config" / "twinslam.yaml"
#: the paper's Table I device: the file every committed figure of the paper's device takes
PAPER_PARAMS = REPO / "config" / "paper-table1.yaml"


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
    #: the camera waits for the device beyond this many unposed frames (0: real time)
    pace_frames: int = 0
    record: Path | None = None       #: a rosbag2 (MCAP) folder to record the run into
    #: what the recording keeps, and how
    recording: RecordingOptions = field(default_factory=RecordingOptions)


class Launcher:
    """Starts the nodes on ``domain`` and watches them; ``run`` blocks until the sequence is
    played and the edge has answered its last full slot."""

    NODES = ("edge_mapper", "udt_node", "device_tracker", "sequence_player")

    def __init__(self, domain: ProcessDomain, config: LaunchConfig,
                 echo: Callable[[str], None] | None = print) -> None:
        self.domain, self.config, self.echo = domain, config, echo
        self.procs: dict[str, NodeProcess] = {}
        self.logs: dict[str, str] = {}         #: each node's stderr (its log), after stop
        self._killed: set[int] = set()         #: pids killed on purpose (``kill``)
        #: what the monitor heard, by slot: filled while ``run`` plays, kept afterwards
        self.record: RunLog | None = None
        #: what ``config.record`` holds after the run (None: not recorded)
        self.recording: RecordingSummary | None = None
        #: the playback's end, when a run asks for it (``end_playback``)
        self._end: PlaybackEnd | None = None
        self._end_requested = False

    def node_args(self, name: str) -> list[str]:
        c = self.config
        args = ["-m", NODE_MODULES[name], "--ros-args", "--params-file", str(c.params_file)]
        params = {"edge_mapper": [f"policy:={c.policy}"]
                  + ([f"checkpoint:={c.checkpoint}"] if c.checkpoint else []),
                  "sequence_player": [f"sequence:={c.sequence}", f"rate:={c.rate}",
                                      f"start:={c.start}",
                                      f"end:={c.start + c.frames if c.frames > 0 else -1}",
                                      # the device, and the monitor when it views or
                                      # records images
                                      f"wait_for_subscribers:="
                                      f"{1 + c.watch_images + (c.record is not None)}"]
                  + ([f"pace_frames:={c.pace_frames}"] if c.pace_frames else []),
                  }.get(name, [])
        params += c.scenario.node_params(c.frames, self._recorded_slot()[1]).get(name, []) \
            + c.extra.get(name, [])
        if name == "device_tracker":
            params += self._device_slot_params()
        for p in params:
            args += ["-p", p]
        return args

    def start(self, name: str) -> NodeProcess:
        proc = self.domain.spawn(self.node_args(name), host=NODE_HOSTS[name],
                                 forks=preloaded_nodes())
        self.procs[name] = proc
        return proc

    def run(self, on_stats: Callable[[Any, RunLog], None] | None = None) -> RunReport:
        """Play, watch, stop; ``on_stats(msg, record)`` runs on every ``MapStats`` (tests use
        it to inject faults mid-run, and to end the playback once what they wait for came:
        ``end_playback``)."""
        with self.domain.monitor_scope():
            return self._run(on_stats)

    def _run(self, on_stats: Callable[[Any, RunLog], None] | None) -> RunReport:
        c = self.config
        session = RosSession("twinslam_monitor", executor="events")
        recorder: RunRecorder | None = None
        try:
            def stats(msg: Any, record: RunLog) -> None:
                if self.echo:
                    self.echo(status_line(msg, record))
                if on_stats:
                    on_stats(msg, record)

            monitor = PipelineMonitor(session.node, stats, c.watch_images)
            if c.record is not None:
                recorder = RunRecorder(session.node, c.record, c.recording)
            self.record = monitor.record
            slot_frames = self._recorded_slot()[0]
            self._end = PlaybackEnd(session.node, slot_frames,
                                    c.scenario.played_frames(c.frames) if c.frames > 0 else None)
            if self._end_requested:
                self._end.request()
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

            def played() -> bool:
                assert self._end is not None
                self._end.poll(max(len(monitor.record.ground_truth),
                                   (max(monitor.record.summaries, default=-1) + 1) * slot_frames))
                return player.poll() is not None or self._failed() is not None

            session.spin_until(played, c.timeout_s)
            # an end the player accepted just before it exited: its answer taken now
            end = self._end
            session.spin_until(lambda: not end.answer_awaited(), END_ANSWER_WAIT_S)
            failed = self._failed()
            if failed:
                _, _, err = self.domain.stop(self.procs.pop(failed))
                raise RuntimeError(f"{failed} exited during the run: {err.strip()[-800:]}")
            if player.returncode not in (0, None):
                _, _, err = self.domain.stop(self.procs.pop("sequence_player"))
                # a player stuck in DDS at its very end (it played everything) lost no run
                if not ended_as_asked(player.returncode, err):
                    raise RuntimeError(f"sequence_player exited with {player.returncode}: "
                                       f"{err.strip()[-500:]}")
            # the device's last summaries may still be in flight (a lossy link retransmits):
            # wait for every full slot of the frames played, or what arrived when unknown
            summaries = monitor.record.summaries
            expected = self.expected_slots()
            last = expected - 1 if expected else (max(summaries) if summaries else -1)
            session.spin_until(lambda: last in monitor.record.stats and all(
                s in monitor.record.throughput for s in monitor.record.requests),
                # at least 10 s even when a slow start (a fresh checkout compiles its kernels)
                # used up most of the run's timeout
                min(60.0, max(10.0, deadline - time.monotonic())))
            # the device's pose of the last frame played: a device behind the camera (a loaded
            # machine) publishes it after the player has ended, and a recording closed before
            # it lacks the last poses (bounded: a device that dropped that frame never sends it;
            # not cut by the run's deadline, which a slow start — a lagging device — used up)
            truth = monitor.record.ground_truth
            session.spin_until(lambda: not truth or max(truth) in monitor.record.poses,
                               LAST_POSE_WAIT_S)
            session.spin_until(lambda: False, 0.5)       # late map updates
            return report(c.policy, monitor.record, time.monotonic() - started, slot_frames)
        finally:
            self.stop()
            if recorder is not None:
                self.recording = recorder.close()
            session.close()

    def expected_slots(self) -> int | None:
        """Full slots in the frames played (None when the whole sequence plays and no end was
        asked for)."""
        slot_frames = self._recorded_slot()[0]
        if self._end is not None and self._end.frames is not None:
            return self._end.frames // slot_frames
        if self.config.frames <= 0:
            return None
        return self.config.scenario.played_frames(self.config.frames) // slot_frames

    def end_playback(self) -> None:
        """End the playback at the end of the next slot the player has not passed (from
        ``on_stats`` or before ``run``): a run that waits for an event plays generously many
        frames and ends once the event came, so that a slower machine plays more, not a run
        too short for what it checks. ``config.frames`` stays the most it plays."""
        self._end_requested = True
        if self._end is not None:
            self._end.request()

    def _device_given(self) -> dict[str, object]:
        """The device parameters the run gives, as the node will read them: ``extra`` over
        the parameter file (the node's defaults for the rest)."""
        given = dict(node_parameters(self.config.params_file, "device_tracker"))
        for item in self.config.extra.get("device_tracker", []):
            key, _, value = item.partition(":=")
            given[key] = value
        return given

    def _device_slot_params(self) -> list[str]:
        """What the device is told of its slot beyond what the run gives it, as the camera
        plays: slots are cut by stamps, so replayed faster its frames come faster — its frame
        rate × the run's ``rate`` (nothing at the recorded speed)."""
        if self.config.rate == 1.0:
            return []
        _, rate = played_device_slot(self._device_given(), rate=self.config.rate)
        return [f"frame_rate_hz:={rate!r}"]

    def _recorded_slot(self) -> tuple[int, float]:
        """The device's slot frames and nominal frame rate as given, for a camera playing
        every frame at the recorded speed."""
        return played_device_slot(self._device_given())

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


def preloaded_nodes() -> ForkServers | None:
    """The fork servers the launchers start their nodes from (``twinslam.live.node_fork_server``),
    unless ``TWINSLAM_FORK_SERVER=0`` asks for a ``python -m`` process each."""
    return None if os.environ.get(SWITCH, "1") == "0" else fork_servers(REPO)


def renamed_params(params_file: Path, node: str, name: str, folder: Path) -> Path:
    """A copy of ``params_file`` in ``folder`` in which node ``name`` finds what the file
    gives ``node`` (``/**`` as it is): a node renamed at launch (``-r __node:=NAME``) reads
    only its own name's section, and a parameter file's names take no wildcard within a
    word."""
    doc = yaml.safe_load(Path(params_file).read_text(encoding="utf-8")) or {}
    section = doc.get(node) or doc.get(f"/{node}") or doc.get(any_namespace(node))
    if section is not None:
        doc[name] = copy.deepcopy(section)          # a shared one would be written as an alias
    out = Path(folder) / f"{name}.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return out


def namespaced_params(params_file: Path, folder: Path) -> Path:
    """A copy of ``params_file`` in ``folder`` in which every node section under a plain name
    (``device_tracker:`` or ``/device_tracker:``) is keyed ``/**/device_tracker`` instead, so
    that a node of that name reads it in whatever namespace it runs. A fleet runs each device
    and player under its device's namespace (``/ar1``); rcl gives such a node no section
    keyed by its plain name, and it started on its defaults whatever the file said. Keys
    that name a namespace or a wildcard already, and ``/**``, stay as they are; a plain
    section merges over a wildcard one of the same node (its values win)."""
    doc = yaml.safe_load(Path(params_file).read_text(encoding="utf-8")) or {}

    def plain(key: object) -> bool:
        name = str(key).removeprefix("/")
        return key != EVERY_NODE and "/" not in name and isinstance(doc[key], dict)

    out = {key: copy.deepcopy(body) for key, body in doc.items() if not plain(key)}
    for key in filter(plain, doc):
        section = out.setdefault(any_namespace(str(key).removeprefix("/")), {})
        values = {**(section.get("ros__parameters") or {}),
                  **(doc[key].get("ros__parameters") or {})}
        section.update(copy.deepcopy(doc[key]))
        section["ros__parameters"] = copy.deepcopy(values)
    path = Path(folder) / "namespaced.yaml"
    path.write_text(yaml.safe_dump(out, sort_keys=False), encoding="utf-8")
    return path


def player_camera(params_file: Path) -> str:
    """The camera the player shows the device with ``params_file``: its ``colour_intrinsics``
    (the node's default, ``auto``, where the file names none) — the camera the simulator's
    view of the same frames must be extracted through."""
    return str(node_parameters(params_file, "sequence_player").get("colour_intrinsics", AUTO))


def tc_uplink_params(alpha_mbit: float, **device: str) -> dict[str, list[str]]:
    """Node parameters for an uplink shaped by tc that carries real frames (each keyframe with
    its image): α, the frame's size in Mbit, the same on device and edge so that Theorem 1's
    |U_k| fits D_req; ``device`` adds device parameters (e.g. ``netem_delay_ms="2"``)."""
    alpha = f"alpha_mbit:={alpha_mbit:g}"
    return {"device_tracker": ["shaper:=tc", "upload_image:=true", alpha,
                               *(f"{k}:={v}" for k, v in device.items())],
            "edge_mapper": [alpha]}
