"""``twinslam launch``: player, device, edge (and twin) as processes, one run per policy."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path
from typing import TypeVar

from twinslam.cli.arguments import add_pace_argument
from twinslam.cli.commands.launch_fleet import (
    add_fleet_arguments,
    domain_for,
    places_of,
    run_fleets,
)
from twinslam.cli.console import Subparsers, each_run, error
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.hosts.netns import unavailable_reason
from twinslam.live.launcher import (
    DEFAULT_PARAMS,
    LaunchConfig,
    Launcher,
    tc_uplink_params,
)
from twinslam.live.node_logs import write_logs
from twinslam.live.parameter_files import node_parameters
from twinslam.live.report import RunReport, policy_label, print_table
from twinslam.live.run_bag import (
    CHUNK_MODES,
    IMAGE_MODES,
    RecordingOptions,
    check_destination,
)
from twinslam.live.run_checks import params_file_problem, policy_problem
from twinslam.live.run_picture import plot_run
from twinslam.live.scenarios import SCENARIOS, Scenario, scenario
from twinslam.live.slot_table import write_slot_table
from twinslam.policies.registry import LEARNED_PREFIX
from twinslam.reporting import file_name
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.map_source import DEFAULT_MAP_SOURCE, check_map_source
from twinslam.slot_protocol import default_device
from twinslam.uplink.families import FAMILIES

R = TypeVar("R")


def _real_frame_uplink(sequence: str) -> dict[str, list[str]]:
    """tc-shaped uplink parameters whose α is the sequence's first colour image as rgb8."""
    first = next(iter(open_sequence(sequence, 0, 1)))
    return tc_uplink_params(first.color.nbytes * 8 / 1e6)


def _checked_setup(args: argparse.Namespace
                   ) -> tuple[list[str], Scenario, dict[str, list[str]]]:
    """The runs' policies (:func:`policies_of`), the scenario and the node parameters every
    run adds; ValueError names a bad option before any node starts."""
    problem = params_file_problem(args.params)
    if problem:
        raise ValueError(f"--params: {problem}")
    policies = policies_of(args)
    if not policies:
        raise ValueError("--policy: name at least one policy")
    for policy in policies:
        problem = policy_problem(policy)
        if problem:
            raise ValueError(f"--policy: {problem}")
    if args.tc and not args.hosts:
        raise ValueError("--tc shapes the device host's uplink: use it with --hosts")
    if args.hosts:
        why = unavailable_reason()
        if why:
            raise ValueError(f"--hosts: {why}")
    try:
        chosen = scenario(args.scenario)
    except ValueError as exc:
        raise ValueError(f"--scenario: {exc}") from None
    places = places_of(args.sequence)
    if places and not args.devices:
        raise ValueError(f"--sequence: {len(places)} places ({args.sequence}) need --devices: "
                         "a fleet's devices walk them")
    if args.every != 1 and not args.devices:
        raise ValueError(f"--every {args.every}: a fleet's option (--devices N); one device "
                         "plays one frame in N with `-p every:=N` on its player")
    extra = _real_frame_uplink(places[0] if places else args.sequence) if args.tc else {}
    if args.map_source is not None:
        reason = check_map_source(args.map_source)
        if reason:
            raise ValueError(f"--map-source: {reason}")
        extra.setdefault("device_tracker", []).append(f"map_source:={args.map_source}")
    return policies, chosen, extra


def played_frames(args: argparse.Namespace, chosen: Scenario) -> str:
    """The frames a run plays, as its header says it: the sequence's frames in [start,
    start + frames) (to its end with -1, or when it holds fewer), forward — or forward then
    back, the turning frame once. SequenceError for a range the sequence does not hold."""
    end = -1 if args.frames < 0 else args.start + args.frames
    selected = len(open_sequence(args.sequence, args.start, end))
    if chosen.order == "forward":
        return f"{selected} frames"
    return f"{chosen.played_frames(selected)} frames ({selected} forward then back)"


def _recordings(args: argparse.Namespace, policies: list[str]) -> dict[str, Path | None]:
    """Where each policy's run is recorded: ``--record DIR`` itself for one policy, DIR/POLICY
    for several; every destination checked before any run (ValueError)."""
    if args.record is None:
        return dict.fromkeys(policies)
    if args.record_camera_every < 1:
        raise ValueError(f"--record-camera-every must be >= 1, got {args.record_camera_every}")
    if len(policies) == 1:
        out: dict[str, Path | None] = {policies[0]: args.record}
    else:
        args.record.mkdir(parents=True, exist_ok=True)
        out = {p: args.record / file_name(policy_label(p)) for p in policies}
    for folder in out.values():
        assert folder is not None
        check_destination(folder)
    return out


def _run_policy(args: argparse.Namespace, policy: str, chosen: Scenario,
                extra: dict[str, list[str]], record: Path | None, played: str) -> RunReport:
    # a learned policy decides on the twin node's latents: start it with its checkpoint
    kind, _, checkpoint = policy.partition(":")
    learned = kind == LEARNED_PREFIX and bool(checkpoint)
    run_extra = {**extra, **({"udt_node": [f"policy_checkpoint:={checkpoint}"]}
                             if learned else {})}
    config = LaunchConfig(args.sequence, policy, args.frames, args.rate, args.params,
                          with_twin=args.twin or learned, timeout_s=args.timeout,
                          extra=run_extra, scenario=chosen, start=args.start,
                          pace_frames=args.pace, record=record, recording=RecordingOptions(
                              args.record_camera_every, args.record_images, args.record_chunks))
    with domain_for(args) as dom:
        if isinstance(dom, LoopbackDomain) and args.loopback:
            dom.activate()
        where = ("hosts device/edge/twin, domain" if args.hosts else
                 "loopback domain" if args.loopback else "domain")
        paced = (f", the camera waiting for the device beyond {args.pace} unposed frames"
                 if args.pace else "")
        print(f"{policy}: {played} of {args.sequence} at {args.rate}x{paced} on {where} "
              f"{dom.domain_id}", flush=True)
        launcher = Launcher(dom, config, lambda line: print(line, flush=True))
        report = launcher.run()
    if launcher.recording is not None:
        r = launcher.recording
        print(f"recorded {r.messages} messages, {r.bytes / 1e6:.1f} MB in {r.path} "
              f"({r.mb_per_minute:.0f} MB a minute of run)", flush=True)
    if launcher.record is not None:
        picture = args.out / f"{file_name(policy_label(policy))}.png"
        plot_run(launcher.record, f"{report.label}: {played} of {args.sequence}, "
                 f"scenario {args.scenario}", picture)
        slots = picture.with_suffix(".slots.csv")
        write_slot_table(launcher.record, slots)
        write_logs(launcher.logs, picture.with_suffix(".log"))
        print(f"wrote {picture}, {slots} and the nodes' logs", flush=True)
    return report


def policies_of(args: argparse.Namespace) -> list[str]:
    """The runs' policies: ``--policy``'s, or — without it — the one the parameter file gives
    the edge (``adapt`` in the paper's preset), as ``ros2 launch twinslam twinslam_launch.py``
    takes it; the default device's where the file names none. The file is one
    :func:`~twinslam.live.run_checks.params_file_problem` passed."""
    spec = args.policy
    if spec is None:
        spec = str(node_parameters(args.params, "edge_mapper").get("policy",
                                                                   default_device.POLICY))
    return [p.strip() for p in spec.split(",") if p.strip()]


def run(args: argparse.Namespace) -> int:
    try:
        policies, chosen, extra = _checked_setup(args)
        if args.devices:
            return run_fleets(args, policies, chosen, extra)
        records = _recordings(args, policies)
        played = played_frames(args, chosen)
    except (ValueError, SequenceError) as exc:
        return error(exc)
    reports = each_run([functools.partial(_run_policy, args, policy, chosen, extra,
                                       records[policy], played) for policy in policies])
    if isinstance(reports, int):
        return reports
    print()
    print_table(reports)
    return 0


def register(sub: Subparsers) -> None:
    launch = sub.add_parser("launch", help="run player, device, edge (and twin) as processes")
    launch.add_argument("--sequence", default="synthetic",
                        help="SUN3D / 7-Scenes / TUM folder, MCAP bag, synthetic[:frames] "
                        "(the room) or synthetic-corridor[:frames] (where the map matters); "
                        "with --devices, several comma-separated: places, the devices split "
                        "among them in runs of neighbours (ar1 … on the first), each edge "
                        "(--edges) serving whole places")
    launch.add_argument("--policy",
                        help="the edge's policy, one run each, comma-separated: lff, pu, adapt, "
                        "random, mbrl:CHECKPOINT; default: the parameter file's (lff in "
                        "config/twinslam.yaml, the default device's; adapt in "
                        "config/paper-table1.yaml)")
    launch.add_argument("--frames", type=int, default=600, help="frames to play; -1: all")
    launch.add_argument("--start", type=int, default=0,
                        help="the sequence's first frame played; default %(default)s")
    launch.add_argument("--rate", type=float, default=1.0,
                        help="playback speed, × the recorded frame rate")
    add_pace_argument(launch)
    launch.add_argument("--params", type=Path, default=DEFAULT_PARAMS,
                        help="ROS 2 parameter file for the nodes; default the bundled "
                        "config/twinslam.yaml (the default device); config/paper-table1.yaml: "
                        "the paper's Table I device")
    launch.add_argument("--twin", action="store_true",
                        help="start udt_node too (a learned policy's run always does, with "
                        "its checkpoint's twin)")
    launch.add_argument("--loopback", action="store_true",
                        help="a private loopback DDS domain instead of $ROS_DOMAIN_ID")
    launch.add_argument("--hosts", action="store_true",
                        help="device, edge and twin in network namespaces of their own (root)")
    launch.add_argument("--tc", action="store_true",
                        help="with --hosts: the device's uplink shaped by tc at d_k, keyframes "
                        "carrying their image")
    launch.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds a policy's run may take before its nodes are stopped")
    launch.add_argument("--scenario", default="forward",
                        help="; ".join(f"{s.name}: {s.description}" for s in SCENARIOS.values()
                                       ).replace("%", "%%") + "; NAME@FAMILY: over an uplink "
                        "family (" + ", ".join(FAMILIES) + "); default %(default)s")
    launch.add_argument("--out", type=Path, default=Path("results/launch"),
                        help="folder for a picture of each policy's run (POLICY.png: the "
                        "final map from above with the trajectories, per-slot map size, υ, "
                        "lost share and uplink rate) and its slots (POLICY.slots.csv: which "
                        "policy decided each slot, what it asked for and the map after it), "
                        "and every node's log (POLICY.log; with --devices, "
                        "POLICY_ALLOCATOR.log beside POLICY_ALLOCATOR_DEVICE.png and "
                        "fleet_runs.csv); default %(default)s")
    launch.add_argument("--record", type=Path, default=None, metavar="DIR",
                        help="record each run as a rosbag2 (MCAP) that RViz, Foxglove and "
                        "rosbags open: every topic, the camera decimated (DIR itself for one "
                        "policy, DIR/POLICY for several; refused before the run when DIR "
                        "exists, is not writable or the disk is nearly full)")
    launch.add_argument("--record-camera-every", type=int, default=10, metavar="N",
                        help="with --record: keep one camera sample (image, depth, "
                        "camera_info) in N")
    launch.add_argument("--record-images", choices=IMAGE_MODES, default="raw",
                        help="with --record: the camera's images as they were published (raw) "
                        "or as sensor_msgs/CompressedImage on image_transport's .../compressed "
                        "topics (colour JPEG, 16-bit depth lossless PNG: docs/running.md, "
                        "'Pictures, slot logs and recordings', has the MB a minute both ways); "
                        "default %(default)s")
    launch.add_argument("--record-chunks", choices=CHUNK_MODES, default="zstd",
                        help="with --record: the MCAP chunks zstd-compressed (lossless; every "
                        "MCAP reader decodes them) or stored as they are; default %(default)s")
    add_fleet_arguments(launch)
    launch.add_argument("--map-source", default=None,
                        help="the device's map source: edge (tracked only against the edge's "
                        "map, the paper's device) or edge+local (plus its own recent points); "
                        "default: the parameter file's, which is "
                        f"{DEFAULT_MAP_SOURCE} in the bundled one, as twinslam evaluate's")
    launch.set_defaults(func=run)
