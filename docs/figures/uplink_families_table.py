"""The table of docs/results/any-uplink.md, "Uplink families": what each family's traces hold
over the seeds a sweep draws, per 2 s slot (the rate a slot's uploads get).

    .venv/bin/python docs/figures/uplink_families_table.py [--seeds 10] [--minutes 10]

Per family: its channel spec, then over ``--seeds`` traces of ``--minutes`` each — the median
slot rate, the share of slots under 10 Mbit/s (where Theorem 1 uploads nothing at Table I's
α and D_req) and under 20 (nothing at D_req 0.25 s), the share of slots down (0 Mbit/s), and
the longest run of down slots in seconds. A Markov family is drawn from its chain.
"""

from __future__ import annotations

import argparse

import numpy as np

from twinslam.uplink.channels import parse_channel
from twinslam.uplink.families import FAMILIES

SLOT_S = 2.0


def slot_rates(channel: str, rate_mbps: tuple[float, float] | None, seed: int,
               slots: int) -> np.ndarray:
    """``slots`` slot rates (Mbit/s) of ``channel`` drawn for ``seed``."""
    chan = parse_channel(channel, rate_mbps or (40.0, 80.0), seed)
    chan.reset(seed)
    return np.array([chan.step()[1] for _ in range(slots)])


def longest_down_s(rates: np.ndarray) -> float:
    """The longest run of slots at 0 Mbit/s, in seconds."""
    longest = run = 0
    for rate in rates:
        run = run + 1 if rate == 0 else 0
        longest = max(longest, run)
    return longest * SLOT_S


def table(seeds: int, minutes: float) -> str:
    slots = round(minutes * 60 / SLOT_S)
    lines = ["| family | channel | seeds | median slot rate (Mbit/s) | slots under 10 Mbit/s | "
             "under 20 Mbit/s | slots down | longest down (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for family in FAMILIES.values():
        drawn = [slot_rates(family.channel, family.rate_mbps, s, slots) for s in range(seeds)]
        rates = np.concatenate(drawn)
        lines.append(f"| {family.name} | `{family.channel}` | {seeds} | "
                     f"{np.median(rates):.1f} | {np.mean(rates < 10):.1%} | "
                     f"{np.mean(rates < 20):.1%} | {np.mean(rates == 0):.1%} | "
                     f"{max(longest_down_s(r) for r in drawn):.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10, help="traces per family (seeds 0..)")
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of each trace")
    args = parser.parse_args(argv)
    print(table(args.seeds, args.minutes))


if __name__ == "__main__":
    main()
