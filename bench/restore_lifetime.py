"""How long a keyframe the edge restores from its archive stays in the map, per policy, in the
simulator: slots from the slot that brought it back to the first slot that evicts it again.

The rule policies read keyframe ids as capture order: LFF and PU evict the *oldest* map
frames, and a restored keyframe is old by capture whatever it is worth now — a restore
LFF evicts again at the very next slot lived one slot. ADAPT and random do not look at
ids. The same walk, uplink and restores for each policy, seed by seed.

    .venv/bin/python -m bench.restore_lifetime [--policy restore:lff,restore:adapt]
        [--seeds 10] [--slots 34] [--vmax 15] [--restores 3] [--csv FILE]
"""

from __future__ import annotations

import argparse
import csv
import statistics
from pathlib import Path

from bench.paths import REPO
from twinslam.cli.arguments import DEFAULT_CHANNEL
from twinslam.covisibility.dataset import load_covisibility
from twinslam.policies.actions import MapAction
from twinslam.policies.plan import rollout
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.uplink.channels import parse_channel

COVIS = REPO / "data" / "7scenes-redkitchen-1000.covis.npz"


def lifetimes(actions: list[MapAction]) -> list[tuple[int, int, int | None]]:
    """For each restore of the episode, in order: (its slot, the keyframe, the slots until an
    action evicts that keyframe again — 1: the very next slot; None when none does before
    the episode ends)."""
    out: list[tuple[int, int, int | None]] = []
    for k, action in enumerate(actions):
        for kf in action.restore:
            out.append((k, kf, next((j - k for j in range(k + 1, len(actions))
                                     if kf in actions[j].evict), None)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--covis", type=Path, default=COVIS,
                        help="covisibility dataset (default: the bundled 7-Scenes walk's)")
    parser.add_argument("--policy", default="restore:lff,restore:pu,restore:adapt,restore:random",
                        help="comma-separated restoring policies (default %(default)s)")
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 (default %(default)s)")
    parser.add_argument("--slots", type=int, default=34,
                        help="slots an episode (default %(default)s: the walk forward and back)")
    parser.add_argument("--vmax", type=int, default=15, help="V_max (default %(default)s)")
    parser.add_argument("--restores", type=int, default=3,
                        help="keyframes the edge may restore a slot (default %(default)s)")
    parser.add_argument("--archive", type=int, default=500,
                        help="the archive's capacity (default %(default)s)")
    parser.add_argument("--channel", default=DEFAULT_CHANNEL,
                        help="the uplink (default %(default)s)")
    parser.add_argument("--csv", type=Path, help="also write one row per restore here")
    args = parser.parse_args()
    dataset = load_covisibility(args.covis)
    config = SimConfig(vmax=args.vmax, slots=args.slots, start=0,
                       archive_keyframes=args.archive, restore_keyframes=args.restores)
    rows: list[dict[str, object]] = []
    print(f"{'policy':<16} {'restores':>8} {'distinct':>8} {'next slot':>10} {'median':>7} "
          f"{'kept to end':>12}")
    for name in [p.strip() for p in args.policy.split(",") if p.strip()]:
        policy = make_policy(name)
        found: list[int | None] = []
        distinct = 0                         # keyframes restored at least once, over the seeds
        for seed in range(args.seeds):
            env = MapManagementEnv(dataset, parse_channel(args.channel, seed=seed), config)
            restores = lifetimes(rollout(env, policy, seed).actions)
            found += [n for _, _, n in restores]
            distinct += len({kf for _, kf, _ in restores})
            rows += [{"policy": name, "seed": seed, "slot": k, "keyframe": kf,
                      "slots_kept": "" if n is None else n} for k, kf, n in restores]
        evicted = [n for n in found if n is not None]
        next_slot = sum(n == 1 for n in evicted) / len(found) if found else float("nan")
        median = statistics.median(evicted) if evicted else float("nan")
        print(f"{name:<16} {len(found):>8} {distinct:>8} {next_slot:>10.1%} {median:>7.1f} "
              f"{(len(found) - len(evicted)) / len(found) if found else float('nan'):>12.1%}")
    if args.csv:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=["policy", "seed", "slot", "keyframe",
                                                    "slots_kept"])
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
