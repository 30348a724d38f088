"""Were the slots without an upload slots the uplink could not carry a frame in?

For every run of a default-device sweep folder whose longest stretch without an upload is
three slots or more, the same seed's uplink as the device drew it (the scenario's channel,
1 s slots) and the longest stretch of slots under α = 5 Mbit a slot among the run's slots.
A no-upload stretch no longer than the uplink's under-α stretch is the uplink's, not the
protocol's (docs/results/default-device-scenarios.md).

    .venv/bin/python docs/figures/default-device/starved_slots.py FOLDER [--frames 599]
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from twinslam.live.scenarios import scenario
from twinslam.slot_protocol import table1
from twinslam.uplink.channels import parse_channel

SLOT_S = 1.0                       #: the default device's slots (30 frames at 30 Hz)


def under_alpha(name: str, seed: int, slots: int) -> int:
    """The longest stretch of the run's ``slots`` whose rate carries less than α a slot."""
    sc = scenario(name)
    channel = parse_channel(sc.channel or "markov:N=2", sc.rate_mbps or (40.0, 80.0), seed,
                            SLOT_S)
    best = run = 0
    for _ in range(slots):
        run = run + 1 if channel.step()[1] * SLOT_S < table1.ALPHA_MBIT else 0
        best = max(best, run)
    return best


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a sweep folder holding runs.csv")
    parser.add_argument("--frames", type=int, default=599,
                        help="camera frames a run played (300 forward and back: 599)")
    args = parser.parse_args(argv)
    slots = math.ceil(args.frames / (SLOT_S * table1.FRAME_RATE_HZ))
    print("| scenario | seed | longest without upload (slots) | longest under α (slots) |")
    print("|---|---|---|---|")
    with (args.folder / "runs.csv").open(newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            starved = float(row["longest_no_upload_slots"])
            if starved >= 3:
                print(f"| {row['scenario']} | {row['seed']} | {starved:.0f} | "
                      f"{under_alpha(row['scenario'], int(row['seed']), slots)} |")


if __name__ == "__main__":
    main()
