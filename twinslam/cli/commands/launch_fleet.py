"""``twinslam launch --devices N``: one edge serving N devices — the options, one
fleet run per policy and allocator, the tables and ``OUT/fleet_runs.csv``; and where any launch
runs its nodes (:func:`domain_for`)."""

from __future__ import annotations

import argparse
import functools
import os

from twinslam.cli.console import each_run, error
from twinslam.hosts.loopback import EnvironmentDomain, LoopbackDomain, ProcessDomain
from twinslam.hosts.netns import NetnsHosts
from twinslam.live.fleet import (
    FLEET_COLUMNS,
    FleetConfig,
    FleetLauncher,
    FleetReport,
    device_sequence,
    fleet_rows,
    print_fleet_table,
    shared_images,
)
from twinslam.live.launcher import LaunchConfig
from twinslam.live.node_logs import write_logs
from twinslam.live.report import policy_label
from twinslam.live.run_picture import plot_run
from twinslam.live.scenarios import Scenario
from twinslam.reporting import append_csv_rows, file_name
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import focal_lengths, is_synthetic, open_sequence, with_focal


def domain_for(args: argparse.Namespace, hosts: tuple[str, ...] | None = None
               ) -> ProcessDomain:
    """Where the nodes run: network-namespace hosts (device/edge/twin, or ``hosts``), a
    private loopback domain, or $ROS_DOMAIN_ID."""
    if args.hosts:
        prefix = f"twinslam{os.getpid()}-"
        return NetnsHosts(prefix=prefix, hosts=hosts) if hosts else NetnsHosts(prefix=prefix)
    return LoopbackDomain() if args.loopback else EnvironmentDomain()


def fleet_settings(args: argparse.Namespace) -> list[FleetConfig]:
    """One fleet configuration per allocator asked for; ValueError names a bad option."""
    if args.record is not None:
        raise ValueError("--devices does not record yet: run without --record")
    allocators = [a.strip() for a in args.allocator.split(",") if a.strip()]
    orders = tuple(o.strip() for o in args.orders.split(",") if o.strip())
    try:
        delays = tuple(float(d) for d in args.delays.split(",") if d.strip())
    except ValueError:
        raise ValueError(f"--delays {args.delays!r}: seconds, one a device (e.g. 0,20)") \
            from None
    fleets = [FleetConfig(args.devices, args.vmax_total, a, args.min_keyframes, args.stride,
                          args.seed, orders, args.merge_maps or args.join_maps, args.edges,
                          delays, places_of(args.sequence), args.one_walk, args.every,
                          join_maps=args.join_maps)
              for a in allocators]
    for fleet in fleets:
        fleet.check()
    focals = device_focals(args)
    if focals and not all(is_synthetic(p) for p in (places_of(args.sequence)
                                                     or (args.sequence,))):
        raise ValueError(f"--focals: a camera of each device's own needs a synthetic place, "
                         f"not {args.sequence}")
    try:
        fleet_starts(args, fleets[0])               # every place can be opened
    except SequenceError as exc:
        raise ValueError(f"--sequence: {exc}") from None
    return fleets


def device_focals(args: argparse.Namespace) -> tuple[float, ...]:
    """``--focals``: each device's camera focal length in pixels (empty: the world's)."""
    try:
        return focal_lengths(getattr(args, "focals", ""))
    except ValueError as err:
        raise ValueError(f"--focals: {err}") from None


def places_of(sequence: str) -> tuple[str, ...]:
    """The places a fleet walks: ``--sequence A,B`` names two (empty for one)."""
    places = tuple(p.strip() for p in sequence.split(",") if p.strip())
    return places if len(places) > 1 else ()


def place_lengths(args: argparse.Namespace, fleet: FleetConfig) -> dict[str, int | None]:
    """Each place's frames (None for a synthetic place: each device renders a walk of its
    own length)."""
    return {p: None if is_synthetic(p) else len(open_sequence(p, 0, -1))
            for p in fleet.places or (args.sequence,)}


def fleet_starts(args: argparse.Namespace, fleet: FleetConfig,
                 by_place: dict[str, int | None] | None = None) -> list[tuple[str, int]]:
    """(sequence, first frame) of each device: its place's (:meth:`FleetConfig.place_of`),
    the devices of one place spread over it as :func:`device_sequence` spreads a fleet;
    ``by_place``: :func:`place_lengths`, where the caller read them already."""
    places = fleet.places or (args.sequence,)
    by_place = by_place or place_lengths(args, fleet)
    lengths = [by_place[p] for p in places]
    members = [[i for i in range(fleet.devices) if fleet.place_of(i) == p]
               for p in range(len(places))]
    focals = device_focals(args)
    starts = []
    for i in range(fleet.devices):
        p = fleet.place_of(i)
        spec, first = device_sequence(places[p], members[p].index(i), len(members[p]),
                                      args.frames, args.start, fleet.stride, lengths[p],
                                      fleet.walk_seed(i))
        starts.append((with_focal(spec, focals[i % len(focals)] if focals else None),
                       first))
    return starts


def run_fleet(args: argparse.Namespace, policy: str, fleet: FleetConfig, chosen: Scenario,
              extra: dict[str, list[str]]) -> FleetReport:
    """One fleet run: its nodes, a picture per device, its rows in OUT/fleet_runs.csv."""
    lengths = place_lengths(args, fleet)
    starts = fleet_starts(args, fleet, lengths)
    config = LaunchConfig(args.sequence, policy, args.frames, args.rate, args.params,
                          timeout_s=args.timeout, extra=extra, scenario=chosen, start=args.start,
                          pace_frames=args.pace)
    with domain_for(args, (*fleet.names(), *fleet.edge_hosts())) as dom:
        if isinstance(dom, LoopbackDomain) and args.loopback:
            dom.activate()
        budget = (f"V_total {fleet.vmax_total} split {fleet.allocator}" if fleet.vmax_total
                  else "each its own V_max")
        edges = "one edge" if fleet.edges == 1 else f"{fleet.edges} edges"
        paced = (f", the cameras waiting together for any device beyond {args.pace} unposed "
                 "frames" if args.pace else "")
        print(f"{policy}: {fleet.devices} devices, {edges} ({budget}), {args.frames} frames "
              f"each{paced} on domain {dom.domain_id}", flush=True)
        for p, place in enumerate(fleet.places):
            walking = [d for i, d in enumerate(fleet.names()) if fleet.place_of(i) == p]
            served = next(e for e, block in zip(fleet.edge_names(), fleet.blocks(),
                                                strict=True) if walking[0] in block)
            print(f"place {p + 1}: {place}, walked by {', '.join(walking)}, served by {served}",
                  flush=True)
        if shared := shared_images(fleet, starts, args.frames, lengths):
            named = ", ".join(f"{a}-{b}" for a, b in shared[:6]) + (" …" if shared[6:] else "")
            print(f"note: {len(shared)} pair(s) of devices replay the same images ({named}): "
                  "a merge may pair an image with itself, which no two real cameras "
                  "capture (--every 2 gives neighbouring devices alternate frames)", flush=True)
        launcher = FleetLauncher(dom, config, fleet, starts, lambda line: print(line, flush=True))
        result = launcher.run_fleet()
    args.out.mkdir(parents=True, exist_ok=True)
    for device, monitor in launcher.records.items():
        picture = args.out / file_name(f"{policy_label(policy)}_{fleet.allocator}_{device}.png")
        plot_run(monitor.record, f"{policy_label(policy)}, {fleet.allocator}: device {device}",
                 picture)
    logs = args.out / file_name(f"{policy_label(policy)}_{fleet.allocator}.log")
    write_logs(launcher.logs, logs)
    print(f"wrote {len(launcher.records)} pictures and the nodes' logs into {args.out}",
          flush=True)
    table = args.out / "fleet_runs.csv"
    period = float(launcher.slot_period_s())
    append_csv_rows(table, FLEET_COLUMNS,
                    fleet_rows(result, fleet.seed,
                               {d: m.record for d, m in launcher.records.items()}, period))
    print(f"appended {fleet.devices} rows to {table}", flush=True)
    return result


def run_fleets(args: argparse.Namespace, policies: list[str], chosen: Scenario,
               extra: dict[str, list[str]]) -> int:
    """Every policy × allocator asked for, then their tables; the exit code."""
    try:
        fleets = fleet_settings(args)
    except ValueError as exc:
        return error(exc)
    results = each_run([functools.partial(run_fleet, args, policy, fleet, chosen, extra)
                        for policy in policies for fleet in fleets])
    if isinstance(results, int):
        return results
    print()
    for result in results:
        print_fleet_table(result)
    return 0


def add_fleet_arguments(launch: argparse.ArgumentParser) -> None:
    """``twinslam launch``'s options of a fleet."""
    fleet = launch.add_argument_group(
        "one edge, many devices", "--devices N plays N devices (namespaces ar1 … arN, each its "
        "own walk and uplink seed) against one edge (or --edges K); a table per device, their "
        "mean and Jain's index of the tracked shares")
    fleet.add_argument("--devices", type=int, default=0, metavar="N",
                       help="devices served by one edge (0: one device/edge pair, as before)")
    fleet.add_argument("--vmax-total", type=int, default=0, metavar="V",
                       help="keyframes of every device's map together (0: each device has "
                       "the parameter file's vmax)")
    fleet.add_argument("--allocator", default="equal",
                       help="how --vmax-total is split, comma-separated to compare: equal, "
                       "motion, twin; default %(default)s")
    fleet.add_argument("--min-keyframes", type=int, default=5,
                       help="the least share a device gets; default %(default)s")
    fleet.add_argument("--seed", type=int, default=0,
                       help="device i's uplink channel (and synthetic-room walk) is seed "
                       "100 x SEED + i; default %(default)s")
    fleet.add_argument("--one-walk", action="store_true",
                       help="on a synthetic place, every device walks one walk (seed 100 x "
                       "SEED), each in its --orders order; without it each walks its own "
                       "(its channel's seed), so two devices from a corridor's two ends may "
                       "never look the same way where they meet")
    fleet.add_argument("--stride", type=int, default=0,
                       help="on a dataset, frames between two devices' first frames (0: "
                       "spread evenly over the sequence)")
    fleet.add_argument("--orders", default="", metavar="ORDER,…",
                       help="each device's order of its frames, one a device: forward, "
                       "backward (from its last frame), forward_backward, backward_forward; e.g. "
                       "forward,backward with --stride set to the sequence's length (both "
                       "play it from its first frame): two devices walking a place from its "
                       "two ends (default: the scenario's for every device)")
    fleet.add_argument("--every", type=int, default=1, metavar="N",
                       help="each camera plays one frame in N, device k the sequence's "
                       "frames numbered k mod N, each at its time in the walk (its device "
                       "told the frame rate and slot_frames divided by N): with --stride set "
                       "to the sequence's length, --every 2 has two devices walk it, in any "
                       "--orders, without ever showing one image, as no two real cameras "
                       "would; default %(default)s (every frame)")
    fleet.add_argument("--focals", default="", metavar="PX,…",
                       help="on a synthetic place, each device's camera focal length in "
                       "pixels, device k the k-th mod their count: devices of one place with "
                       "cameras of their own, e.g. 525,450 (default: the world's 525)")
    fleet.add_argument("--delays", default="", metavar="SECONDS,…",
                       help="seconds each device's camera starts after the fleet's, one a "
                       "device; e.g. 0,20 with --orders forward,forward and --stride set to "
                       "the sequence's length: the second user comes to the place the first "
                       "is mapping 20 s later (default: every device at once)")
    fleet.add_argument("--edges", type=int, default=1, metavar="K",
                       help="edge processes the devices are split among, neighbours together "
                       "(ar1 … arM on edge_mapper, the next on edge_mapper_2, …; with --hosts "
                       "each on a host of its own, edge, edge2, …), each with its devices' "
                       "share of --vmax-total; default %(default)s")
    fleet.add_argument("--merge-maps", action="store_true",
                       help="the edge merges a device's map into the frame of a device before "
                       "it once it finds that device's place (merge_maps); the table then "
                       "gives the cross-device revisit error of each pair in one frame")
    fleet.add_argument("--join-maps", action="store_true",
                       help="--merge-maps where a merge makes the two maps one map of the place "
                       "(merge_join): the place's bundle adjustment and loops run once, each "
                       "device holds a slice of it; the edges write no checkpoint")
