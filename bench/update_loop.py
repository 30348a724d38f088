"""How long the update loop takes, stage by stage (:mod:`twinslam.live.update_loop`): live
runs of player, device and edge as processes on a private loopback domain, the monitor noting
when it heard each slot's summaries, request, throughput report and map, and the device's
frames saying which map they were tracked with.

    python -m bench.update_loop [SEQUENCE] [--frames 300] [--policy lff,adapt] \\
        [--map-source edge] [--scenario revisit-v15] [--seeds 2] [--csv OUT.csv] \\
        [--params config/paper-table1.yaml]

Prints, per policy, the median and p95 of each stage over the runs' slots (a slot whose
stage was not heard is left out of that stage) and the camera frames the device dropped (a
run short of CPU measures the machine, not the loop).
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import asdict, fields
from pathlib import Path

from bench.paths import SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import DEFAULT_PARAMS, LaunchConfig, Launcher
from twinslam.live.scenarios import scenario as scenario_named
from twinslam.live.update_loop import SlotLatency, stage_table, update_loop_latencies
from twinslam.reporting import write_csv

SEQUENCE = SEVEN_SCENES


def run(sequence: str, policy: str, frames: int, map_source: str, scenario: str,
        seed: int, params: Path = DEFAULT_PARAMS) -> tuple[list[SlotLatency], int]:
    """One run's slots and the camera frames its device dropped."""
    extra = {"device_tracker": [f"seed:={seed}", f"map_source:={map_source}"]}
    config = LaunchConfig(sequence, policy, frames, params_file=params,
                          scenario=scenario_named(scenario), extra=extra, timeout_s=600.0)
    with LoopbackDomain() as dom:
        dom.activate()
        launcher = Launcher(dom, config, echo=None)
        report = launcher.run()
    assert launcher.record is not None
    return update_loop_latencies(launcher.record), int(report.frames_dropped)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=HelpFormatter)
    parser.add_argument("sequence", nargs="?", default=str(SEQUENCE),
                        help="an RGB-D sequence (default: the bundled 7-Scenes sample)")
    parser.add_argument("--frames", type=int, default=300, help="frames played a run")
    parser.add_argument("--policy", default="lff,adapt", help="comma-separated edge policies")
    parser.add_argument("--map-source", default="edge",
                        help="the device's map source (edge: the paper's device)")
    parser.add_argument("--scenario", default="revisit-v15", help="the run's scenario")
    parser.add_argument("--seeds", type=int, default=2, help="runs per policy (seeds 0..N-1)")
    parser.add_argument("--params", type=Path, default=DEFAULT_PARAMS,
                        help="the nodes' parameter file (default: the default device's; the "
                        "figures in BENCHMARKS.md before 2026-11-28 are the paper's Table I "
                        "device's, config/paper-table1.yaml)")
    parser.add_argument("--csv", type=Path, default=None,
                        help="write every slot's stages (policy, seed, slot, stages) here")
    args = parser.parse_args()
    print(f"update loop: {platform.processor() or platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {args.frames} frames of "
          f"{args.sequence}, {args.scenario}, {args.map_source} device, {args.seeds} seeds")
    rows: list[list[object]] = []
    for policy in args.policy.split(","):
        slots: list[SlotLatency] = []
        dropped = 0
        for seed in range(args.seeds):
            found, lost = run(args.sequence, policy, args.frames, args.map_source,
                              args.scenario, seed, args.params)
            slots += found
            dropped += lost
            rows += [[policy, seed, *asdict(s).values()] for s in found]
            print(f"  {policy} seed {seed}: {len(found)} slots, {lost} camera frames dropped",
                  flush=True)
        print(f"\n{policy}: {len(slots)} slots, {dropped} camera frames dropped")
        print("| stage | median (ms) | p95 (ms) | slots |\n|---|---|---|---|")
        for name, median, p95, n in stage_table(slots):
            print(f"| {name.replace('_', ' ')} | {1000 * median:.0f} | {1000 * p95:.0f} | {n} |")
    if args.csv is not None:
        write_csv(args.csv, ["policy", "seed", *(f.name for f in fields(SlotLatency))], rows)
        print(f"\nwrote {args.csv}")


if __name__ == "__main__":
    main()
