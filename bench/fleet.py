"""Many devices in the simulator: device-slots per second of one edge's budget
split between N devices, per allocator, on one core — each device a full simulator slot
(decide, map update, υ of the next slot under the device's rule) plus what its allocator reads
(novelty, or the value curve with the device's regime twin).

The bar set for it is ≥ 1 000 device-slots/s at ≥ 100 devices; the gauge (M Python steps/s) is
printed before and after, with each figure divided by it, so that readings taken in another
phase of this VM's speed compare.

    python -m bench.fleet [--devices 10,100,300] [--slots 20] [--policy lff]
"""

from __future__ import annotations

import argparse
import csv
import platform
import re
import time
from pathlib import Path

from bench.gauge import cpu_gauge
from twinslam.covisibility.dataset import CovisibilityDataset, load_covisibility
from twinslam.policies.rules import make_rule_policy
from twinslam.policies.world_model import SimConfig
from twinslam.simulator.fleet import FleetConfig, FleetSimulator
from twinslam.uplink.channels import parse_channel

REAL_COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"


def device_slots_per_s(n: int, allocator: str, policy: str, slots: int,
                       data: CovisibilityDataset | None = None) -> float:
    """Device-slots a second of a fleet of ``n`` (a warm-up episode first, then one timed)."""
    data = data if data is not None else load_covisibility(REAL_COVIS)
    config = FleetConfig(n, 15 * n, allocator, 5, sim=SimConfig(slots=slots))
    sim = FleetSimulator([(data, parse_channel("markov:N=2", seed=i)) for i in range(n)],
                         config, lambda: make_rule_policy(policy))
    sim.run(99)                                    # kernels compiled, caches warm
    started = time.perf_counter()
    sim.run(0)
    return n * slots / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", default="10,100,300", help="fleet sizes, comma-separated")
    parser.add_argument("--slots", type=int, default=20, help="slots per measured episode")
    parser.add_argument("--policy", default="lff", help="every device's policy")
    parser.add_argument("--csv", type=Path, default=None,
                        help="also write devices, allocator, device-slots/s, per M steps/s")
    args = parser.parse_args()
    sizes = [int(x) for x in args.devices.split(",")]
    print(f"machine: {platform.machine()}, python {platform.python_version()}; 7-Scenes "
          f"covisibility, V_total 15 per device, policy {args.policy}, one process")
    before = cpu_gauge()
    print(before, "(before)")
    steps = float(re.search(r"([\d.]+) M Python", before).group(1))   # type: ignore[union-attr]
    print(f"{'devices':>8} {'allocator':>9} {'device-slots/s':>15} {'per M steps/s':>14}")
    rows = []
    for n in sizes:
        for allocator in ("equal", "motion", "twin"):
            rate = device_slots_per_s(n, allocator, args.policy, args.slots)
            rows.append((n, allocator, rate, rate / steps))
            print(f"{n:>8} {allocator:>9} {rate:>15.0f} {rate / steps:>14.1f}", flush=True)
    print(cpu_gauge(), "(after)")
    if args.csv:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(["devices", "allocator", "device_slots_per_s", "per_m_steps"])
            writer.writerows((n, a, f"{r:.1f}", f"{g:.2f}") for n, a, r, g in rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
