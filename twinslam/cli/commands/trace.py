"""``twinslam trace``: generate a synthetic uplink trace, or describe a trace file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from twinslam.cli.arguments import rate_range
from twinslam.cli.console import Subparsers, error
from twinslam.uplink.channels import SLOT_SECONDS, TraceChannel, parse_channel
from twinslam.uplink.families import FAMILIES, uplink_family
from twinslam.uplink.traces import TraceShape, generate_trace, write_trace


def outage(text: str) -> tuple[float, float]:
    """``--outage START:SECONDS`` of ``twinslam trace generate``."""
    start, sep, length = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(start), float(length)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be START:SECONDS, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    """Generate a throughput trace, or describe one (what a trace channel will replay)."""

    try:
        if args.action == "family":
            return describe_family(args.file or "", args.seed, args.states)
        if args.action == "generate":
            if not args.output:
                raise ValueError("generate needs -o/--output FILE")
            shape = TraceShape(seconds=args.seconds, sample_s=args.sample,
                               rate_range=args.rate_range, regime_s=args.regime,
                               noise=args.noise, outages=tuple(args.outage or ()),
                               outage_every_s=args.outage_every, outage_s=args.outage_length)
            times, mbps = generate_trace(shape, args.seed)
            write_trace(Path(args.output), times, mbps)
            print(f"wrote {args.output}: {times.size} samples over {args.seconds:g} s, mean "
                  f"{mbps.mean():.1f} Mbit/s, {100 * (mbps == 0).mean():.1f} % of the time down")
            path = Path(args.output)
        else:
            if not args.file:
                raise ValueError("info needs a trace FILE")
            path = Path(args.file)
        chan = TraceChannel.from_csv(path, args.states, slot_seconds=SLOT_SECONDS)
    except ValueError as exc:
        return error(exc)
    print_slots(str(path), chan)
    return 0


def print_slots(name: str, chan: TraceChannel) -> None:
    """What a trace channel replays, slot by slot: its rates, how often it is down or under
    10 Mbit/s (where Theorem 1 uploads nothing at Table I's α and D_req), its states."""
    slots = chan.slot_rates()
    print(f"{name}: {chan.duration_s:.1f} s, {slots.size} slots of {chan.slot_seconds:g} s; "
          f"per-slot Mbit/s min {slots.min():.1f}, median {np.median(slots):.1f}, max "
          f"{slots.max():.1f}; {np.mean(slots == 0):.1%} of slots down, "
          f"{np.mean(slots < 10):.1%} under 10 Mbit/s")
    print(f"{chan.n_states} states by the trace's quantiles: thresholds "
          f"{', '.join(f'{t:.1f}' for t in chan.quantiser.thresholds)} Mbit/s, representative "
          f"rates {', '.join(f'{r:.1f}' for r in chan.rates)}")


def describe_family(name: str, seed: int, states: int) -> int:
    """``twinslam trace family NAME``: the trace a family draws for ``seed``."""
    try:
        family = uplink_family(name)
    except ValueError as exc:
        return error(exc)
    chan = parse_channel(family.channel, family.rate_mbps or (40.0, 80.0), seed)
    print(f"{family.name}: {family.description}; channel {family.channel}")
    if isinstance(chan, TraceChannel):
        chan.reset(seed)
        print_slots(f"seed {seed}", chan)
    else:
        rates = ", ".join(f"{r:.1f}" for r in chan.rates)
        print(f"a Markov chain over {chan.n_states} states: {rates} Mbit/s")
    return 0


def register(sub: Subparsers) -> None:
    trace = sub.add_parser("trace", help="generate a synthetic uplink trace with regimes and "
                           "outages, or describe a trace file")
    trace.add_argument("action", choices=["generate", "info", "family"],
                       help="generate: write a trace to -o; info: describe FILE as a trace "
                       "channel replays it (duration, per-slot rates, outages, states); "
                       "family: describe the trace an uplink family draws for --seed")
    trace.add_argument("file", nargs="?", help="info: the trace CSV to describe; family: one "
                       f"of {', '.join(FAMILIES)}")
    trace.add_argument("-o", "--output", help="generate: CSV to write (time_s,throughput_mbps)")
    trace.add_argument("--seconds", type=float, default=600.0,
                       help="generate: trace length in s (default %(default)s)")
    trace.add_argument("--sample", type=float, default=0.1,
                       help="generate: s between samples (default %(default)s)")
    trace.add_argument("--rate-range", type=rate_range, default="5,80",
                       help="generate: min,max Mbit/s the regime means are drawn from "
                       "(default 5,80)")
    trace.add_argument("--regime", type=float, default=60.0,
                       help="generate: mean s a regime lasts, exponential (default %(default)s)")
    trace.add_argument("--noise", type=float, default=0.15,
                       help="generate: relative std of samples around the regime mean "
                       "(default %(default)s)")
    trace.add_argument("--outage", type=outage, action="append", metavar="START:SECONDS",
                       help="generate: a 0 Mbit/s outage at START s lasting SECONDS (repeat)")
    trace.add_argument("--outage-every", type=float, default=0.0,
                       help="generate: also random outages, one per this many s on average "
                       "(default 0: none)")
    trace.add_argument("--outage-length", type=float, default=5.0,
                       help="generate: mean s a random outage lasts (default %(default)s)")
    trace.add_argument("--seed", type=int, default=0,
                       help="generate, family: random seed (default 0)")
    trace.add_argument("--states", type=int, default=4,
                       help="N rate states to report quantile thresholds for (default 4)")
    trace.set_defaults(func=run)
