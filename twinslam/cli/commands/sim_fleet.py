"""``twinslam sim --devices N``: allocators of one edge's keyframe budget compared offline
, each device on its own walk and uplink, paired by seed against ``equal``."""

from __future__ import annotations

import argparse
import csv
import math
import time
from collections.abc import Callable
from typing import TypeVar

from twinslam.cli.arguments import covisibility
from twinslam.cli.console import error
from twinslam.covisibility.dataset import CovisibilityError
from twinslam.policies.rules import make_rule_policy
from twinslam.policies.world_model import SimConfig
from twinslam.simulator.fleet import AllocatorResult, FleetConfig, evaluate_fleet
from twinslam.uplink.channels import ChannelError, parse_channel

T = TypeVar("T")


def run_fleet(args: argparse.Namespace) -> int:
    """The fleet comparison the options ask for; the exit code."""
    allocators = [a.strip() for a in args.allocator.split(",") if a.strip()]
    policies = [p.strip() for p in args.policy.split(",") if p.strip()]
    try:
        if len(policies) != 1:
            raise ValueError("--devices compares allocators under one policy: give one "
                             f"--policy (got {', '.join(policies)})")
        make_rule_policy(policies[0])              # a rule policy, refused early if unknown
        total = args.vmax_total or args.vmax * args.devices
        config = FleetConfig(args.devices, total, allocators[0] if allocators else "",
                             args.min_keyframes, args.fairness, args.cell_capacity,
                             cell_split=args.cell_split,
                             sim=SimConfig(slot_frames=args.slot_frames, slots=args.slots))
        for allocator in allocators or [""]:
            FleetConfig(config.devices, total, allocator, config.min_keyframes).check()
        speeds = _cycled(args.speeds, float, "--speeds")
        rates = _cycled(args.device_rates, _rate_range, "--device-rates") or [args.rate_range]
        if any(s < 0 for s in speeds):
            raise ValueError(f"--speeds must be >= 0, got {args.speeds}")
        dataset = covisibility(args.covis)
        for r in rates:
            parse_channel(args.channel, r)
    except (ChannelError, CovisibilityError, ValueError) as exc:
        return error(exc)
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    cell = (f", one cell of {args.cell_capacity:g} Mbit/s split {args.cell_split}"
            if args.cell_capacity else "")
    print(f"{args.devices} devices, one edge: V_total {total} (at least {args.min_keyframes} "
          f"each){cell}; policy {policies[0]}; channel {args.channel} per device; "
          f"{args.slots} slots x {len(seeds)} seeds", flush=True)
    started = time.monotonic()
    report = (lambda m: print(f"  {m}", flush=True)) if args.verbose else None
    if speeds or len(rates) > 1:
        print(f"devices cycle through walking speeds {speeds or [1.0]} and uplink ranges "
              f"{[f'{lo:g}-{hi:g}' for lo, hi in rates]} Mbit/s", flush=True)
    results = evaluate_fleet(dataset,
                             lambda i: parse_channel(args.channel, rates[i % len(rates)], i),
                             config, allocators, lambda: make_rule_policy(policies[0]), seeds,
                             report, (lambda i: speeds[i % len(speeds)]) if speeds else None)
    print_allocators(results)
    print(f"({time.monotonic() - started:.1f} s; per seed the mean over devices; Δ: paired "
          "by seed against equal, the same walks and uplinks; Jain's index of the devices' "
          "tracked shares)")
    if args.csv:
        write_runs(args.csv, results)
        print(f"wrote {args.csv} (one row per device and seed)")
    return 0


def _rate_range(text: str) -> tuple[float, float]:
    low, sep, high = text.partition("-")
    if not sep:
        raise ValueError(f"a rate range is MIN-MAX Mbit/s, got {text!r}")
    return float(low), float(high)


def _cycled(text: str, parse: Callable[[str], T], option: str) -> list[T]:
    """A comma-separated option's values (device i takes value i mod their number)."""
    try:
        return [parse(v.strip()) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ValueError(f"{option}: {exc}") from None


def print_allocators(results: list[AllocatorResult]) -> None:
    base = next((r for r in results if r.allocator == "equal"), None)
    print(f"\n{'allocator':<10} {'mean υ':>9} {'± ci95':>7} {'lost %':>7} {'υ tracked':>10} "
          f"{'Jain':>6} {'Δ lost pts vs equal':>21} {'Δ mean υ vs equal':>19} "
          f"{'dev-slots/s':>11}")
    for r in results:
        mean, ci = r.mean_ci("mean_uncertainty")
        lost, tracked = r.mean_ci("lost_share")[0], r.mean_ci("tracked_uncertainty")[0]
        jain = r.mean_ci("jain_tracked")[0]
        if base is not None and r is not base:
            dl, dl_ci = r.paired(base, "lost_share")
            du, du_ci = r.paired(base, "mean_uncertainty")
            delta = f"{100 * dl:>+11.2f} ± {100 * dl_ci:<7.2f} {du:>+9.1f} ± {du_ci:<7.1f}"
        else:
            delta = f"{'':>21} {'':>19}"
        print(f"{r.allocator:<10} {mean:>9.1f} {ci:>7.1f} {100 * lost:>7.2f} {tracked:>10.1f} "
              f"{jain:>6.3f} {delta} {r.device_slots_per_s:>11.0f}")


def write_runs(path: str, results: list[AllocatorResult]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(["allocator", "seed", "device", "mean_uncertainty", "lost_share",
                         "tracked_uncertainty", "mean_budget"])
        for r in results:
            for run in r.runs:
                for i, d in enumerate(run.devices):
                    budget = sum(d.budgets) / len(d.budgets) if d.budgets else math.nan
                    writer.writerow([r.allocator, run.seed, i, f"{d.tally.mean:.6f}",
                                     f"{d.tally.lost_share:.6f}",
                                     f"{d.tally.tracked_uncertainty:.6f}", f"{budget:.3f}"])
