"""How long a keyframe the edge restores from its archive stays in the map, per policy, in the
simulator: slots from the slot that brought it back to the first slot that evicts it again.

LFF and PU evict the *oldest* map frames. Read by id, a restored keyframe is old by capture
whatever it is worth now: LFF evicted it again at the very next slot. The rules now read the
map's entry order (:meth:`~twinslam.policies.actions.SlotObservation.entry_order`); each
policy runs beside itself reading ids (``by id``: the observation without its entry order,
the rule as it was), on the same walk, uplink and restores seed by seed, and the two are
paired on the lost share and mean υ of each episode.

    .venv/bin/python -m bench.restore_lifetime [--policy restore:lff,restore:adapt]
        [--seeds 10] [--slots 34] [--slot-frames 60] [--d-req 0.5] [--vmax 15]
        [--restores 3] [--csv FILE] [--episodes-csv FILE]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import statistics
from pathlib import Path

from bench.paths import REPO
from twinslam.cli.arguments import DEFAULT_CHANNEL
from twinslam.covisibility.dataset import load_covisibility
from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.plan import Plan, rollout
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.registry import make_policy
from twinslam.policies.restoring import RESTORE_PREFIX, RestoringPolicy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.reporting import mean_ci95, paired_difference
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


class ByCaptureOrder:
    """``policy`` reading the map's ids as its order: the observation without its entry order
    (the rules before they read it)."""

    def __init__(self, policy: MapPolicy) -> None:
        self.policy = policy
        self.name = f"{policy.name} by id"

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed)

    def decide(self, obs: SlotObservation) -> MapAction:
        return self.policy.decide(dataclasses.replace(obs, entered=None))


def by_capture_order(name: str) -> MapPolicy:
    """Policy ``name`` (``restore:POLICY`` or a rule) reading ids as the map's order."""
    kind, _, inner = name.partition(":")
    if kind == RESTORE_PREFIX:
        return RestoringPolicy(ByCaptureOrder(make_policy(inner)))
    return ByCaptureOrder(make_policy(name))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--covis", type=Path, default=COVIS,
                        help="covisibility dataset (default: the bundled 7-Scenes walk's)")
    parser.add_argument("--policy", default="restore:lff,restore:pu,restore:adapt,restore:random",
                        help="comma-separated restoring policies (default %(default)s)")
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 (default %(default)s)")
    parser.add_argument("--slots", type=int, default=34,
                        help="slots an episode (default %(default)s: the walk forward and back)")
    parser.add_argument("--slot-frames", type=int, default=60,
                        help="frames a slot (default %(default)s, Table I's)")
    parser.add_argument("--d-req", type=float, default=0.5,
                        help="D_req in s (default %(default)s, Table I's)")
    parser.add_argument("--vmax", type=int, default=15, help="V_max (default %(default)s)")
    parser.add_argument("--restores", type=int, default=3,
                        help="keyframes the edge may restore a slot (default %(default)s)")
    parser.add_argument("--archive", type=int, default=500,
                        help="the archive's capacity (default %(default)s)")
    parser.add_argument("--channel", default=DEFAULT_CHANNEL,
                        help="the uplink (default %(default)s)")
    parser.add_argument("--csv", type=Path, help="also write one row per restore here")
    parser.add_argument("--episodes-csv", type=Path,
                        help="also write one row per episode here (its lost share, mean υ and "
                        "restores: what the paired differences are made of)")
    args = parser.parse_args()
    dataset = load_covisibility(args.covis)
    config = SimConfig(vmax=args.vmax, slots=args.slots, start=0, slot_frames=args.slot_frames,
                       d_req_s=args.d_req, archive_keyframes=args.archive,
                       restore_keyframes=args.restores)
    rows: list[dict[str, object]] = []
    episode_rows: list[dict[str, object]] = []
    print(f"{'policy':<20} {'restores':>8} {'distinct':>8} {'next slot':>10} {'median':>7} "
          f"{'kept to end':>12} {'lost %':>13} {'mean υ':>15}")
    for name in [p.strip() for p in args.policy.split(",") if p.strip()]:
        episodes: dict[str, list[Plan]] = {}
        for label, policy in ((f"{name} by id", by_capture_order(name)),
                              (name, make_policy(name))):
            plans = episodes[label] = []
            found: list[int | None] = []
            distinct = 0                     # keyframes restored at least once, over the seeds
            for seed in range(args.seeds):
                env = MapManagementEnv(dataset, parse_channel(args.channel, seed=seed), config)
                plan = rollout(env, policy, seed)
                plans.append(plan)
                episode_rows.append({"policy": label, "seed": seed,
                                     "lost_share": plan.tally.lost_share,
                                     "mean_upsilon": plan.tally.mean,
                                     "restores": plan.restored})
                restores = lifetimes(plan.actions)
                found += [n for _, _, n in restores]
                distinct += len({kf for _, kf, _ in restores})
                rows += [{"policy": label, "seed": seed, "slot": k, "keyframe": kf,
                          "slots_kept": "" if n is None else n} for k, kf, n in restores]
            evicted = [n for n in found if n is not None]
            next_slot = sum(n == 1 for n in evicted) / len(found) if found else float("nan")
            median = statistics.median(evicted) if evicted else float("nan")
            kept = (len(found) - len(evicted)) / len(found) if found else float("nan")
            lost = mean_ci95([100 * p.tally.lost_share for p in plans])
            upsilon = mean_ci95([p.tally.mean for p in plans])
            print(f"{label:<20} {len(found):>8} {distinct:>8} {next_slot:>10.1%} {median:>7.1f} "
                  f"{kept:>12.1%} {lost[0]:>7.2f} ± {lost[1]:.2f} {upsilon[0]:>8.1f} ± "
                  f"{upsilon[1]:.1f}")
        by_id, by_entry = episodes[f"{name} by id"], episodes[name]
        def lost_percent(p: Plan) -> float:
            return 100 * p.tally.lost_share

        def mean_upsilon(p: Plan) -> float:
            return p.tally.mean

        for metric, read in (("lost %", lost_percent), ("mean υ", mean_upsilon)):
            diff = paired_difference([[read(p) for p in by_entry]], [read(p) for p in by_id])
            print(f"{'':<20} entry − id, {metric}: {diff.mean:+.2f} [{diff.low:+.2f}, "
                  f"{diff.high:+.2f}]")
    for path, table in ((args.csv, rows), (args.episodes_csv, episode_rows)):
        if path:
            with path.open("w", newline="", encoding="utf-8") as fh:
                writer = csv.DictWriter(fh, fieldnames=list(table[0]))
                writer.writeheader()
                writer.writerows(table)
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
