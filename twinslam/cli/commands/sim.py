"""``twinslam sim``: map-management policies compared offline in the gym-style simulator."""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import dataclass

from twinslam.cli.arguments import (
    DEFAULT_CHANNEL,
    add_executor_arguments,
    add_setting_arguments,
    covisibility,
)
from twinslam.cli.commands.sim_fleet import run_fleet
from twinslam.cli.console import Subparsers, error
from twinslam.covisibility.dataset import CovisibilityError
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import SimConfig
from twinslam.simulator.evaluation import PolicyResult, evaluate
from twinslam.slot_protocol import table1
from twinslam.sweeps import make_executor
from twinslam.uplink.channels import ChannelError


@dataclass(frozen=True)
class Comparison:
    """What one ``twinslam sim`` compares (the command's options; the demo asks for one too)."""

    covis: str
    policies: tuple[str, ...] = ("lff", "pu", "adapt", "reference")
    channel: str = DEFAULT_CHANNEL
    rate_range: tuple[float, float] = (table1.RATE_MIN_MBPS, table1.RATE_MAX_MBPS)
    vmax: int = table1.VMAX
    slot_frames: int = table1.SLOT_FRAMES
    d_req_s: float = table1.D_REQ_S
    slots: int = 200
    seeds: int = 5
    seed0: int = 0
    walk_start: int | None = None
    paper_rule: bool = False
    archive_keyframes: int = 0
    restore_keyframes: int = 0
    csv: str | None = None
    verbose: bool = False
    executor: str = "local"
    jobs: int | None = None
    ray_address: str | None = None


def compare(c: Comparison) -> int:
    """Run every policy over the seeds, print the table (and write the CSV); the exit code."""
    try:
        dataset = covisibility(c.covis)
        config = (SimConfig.paper_rule if c.paper_rule else SimConfig)(
            vmax=c.vmax, slot_frames=c.slot_frames, d_req_s=c.d_req_s, slots=c.slots,
            start=c.walk_start, archive_keyframes=c.archive_keyframes,
            restore_keyframes=c.restore_keyframes)
        seeds = list(range(c.seed0, c.seed0 + c.seeds))
        print(f"covisibility: {dataset.n_frames} frames ({dataset.source or c.covis}); "
              f"channel {c.channel}; V_max {c.vmax}, F {c.slot_frames}, D_req {c.d_req_s:g} s, "
              f"{c.slots} slots x {len(seeds)} seeds"
              + (f"; an archive of {c.archive_keyframes} keyframes, up to "
                 f"{c.restore_keyframes} restored a slot" if c.archive_keyframes else ""),
              flush=True)
        start = time.monotonic()
        with make_executor(c.executor, c.jobs, c.ray_address) as executor:
            results = evaluate(list(c.policies), dataset, c.channel, config, seeds,
                               c.rate_range, progress=lambda m: print(f"  {m}", flush=True),
                               make_policy=make_policy, executor=executor,
                               scores_in_progress=c.verbose)
    except (ChannelError, CovisibilityError, ValueError, RuntimeError) as exc:
        return error(exc)
    _print_table(results, restores=config.restore_keyframes > 0)
    rule_text = ("the paper's rule: lost when no map point is shared" if c.paper_rule else
                 f"lost with fewer than {config.min_shared} shared map points, a slot's first "
                 f"{config.lag_frames} frames on the map before the last update")
    print(f"({time.monotonic() - start:.1f} s; {rule_text}; mean υ scores a lost frame as u = "
          "0, a frame with no map; 'υ tracked' averages the tracked frames; mean υ = (1 - lost)"
          " · υ tracked. The reference is a clairvoyant search, not a bound)")
    if c.csv:
        _write_runs(c.csv, list(c.policies), results)
        print(f"wrote {c.csv} (one row per run)")
    return 0


def _print_table(results: list[PolicyResult], restores: bool = False) -> None:
    """The policies' table; ``restores``: with the archived keyframes each brought back."""
    reference = next((r for r in results if r.policy == "reference"), None)
    width = max(12, *(len(r.policy) for r in results))
    print(f"\n{'policy':<{width}} {'mean υ':>11} {'± ci95':>9} {'lost %':>7} {'υ tracked':>11}"
          f"{' restored/run' if restores else ''}{'  gap to reference' if reference else ''}")
    for r in results:
        gap = f"  {r.mean - reference.mean:+.2f}" if reference else ""
        back = f" {r.restored_per_run:>12.1f}" if restores else ""
        print(f"{r.policy:<{width}} {r.mean:>11.2f} {r.ci95:>9.2f} {100 * r.lost_share:>7.2f} "
              f"{r.tracked_uncertainty:>11.2f}{back}{gap}")


def _write_runs(path: str, specs: list[str], results: list[PolicyResult]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(["policy", "spec", "seed", "mean_uncertainty", "lost_share",
                         "tracked_uncertainty", "restored"])
        for spec, r in zip(specs, results, strict=True):
            for run in r.runs:
                writer.writerow([r.policy, spec, run.seed, f"{run.mean_uncertainty:.6f}",
                                 f"{run.lost_share:.6f}", f"{run.tracked_uncertainty:.6f}",
                                 run.restored])


def run(args: argparse.Namespace) -> int:
    if args.devices:
        if args.executor != "local" or (args.jobs or 1) > 1:
            return error("--executor/--jobs run the seeds of one device's comparison; with "
                         "--devices the allocators run in this process (leave them out)")
        return run_fleet(args)
    policies = tuple(p.strip() for p in args.policy.split(",") if p.strip())
    return compare(Comparison(
        covis=args.covis, policies=policies, channel=args.channel, rate_range=args.rate_range,
        vmax=args.vmax, slot_frames=args.slot_frames, d_req_s=args.d_req, slots=args.slots,
        seeds=args.seeds, seed0=args.seed0, walk_start=args.walk_start,
        paper_rule=args.paper_rule, archive_keyframes=args.archive_keyframes,
        restore_keyframes=args.restore_keyframes, csv=args.csv, verbose=args.verbose,
        executor=args.executor, jobs=args.jobs, ray_address=args.ray_address))


def register(sub: Subparsers) -> None:
    sim = sub.add_parser("sim", help="evaluate map-management policies offline",
                         description="Each policy over --seeds runs of the gym-style simulator "
                         "(covisibility from real frames, a rate model): mean υ with a lost "
                         "frame scoring 0, its 95 % CI, the lost share and υ over tracked "
                         "frames.")
    sim.add_argument("--policy", default=",".join(Comparison.policies),
                     help="comma-separated: lff (latest frames first), pu (periodical "
                     "uploading), adapt (AdaptSLAM's greedy log-det), random, mbrl:CHECKPOINT "
                     "(a policy from `twinslam train`), mpc[:H=3/S=4/rates=regime/frames=motion] "
                     "(the causal planner: H slots ahead over S rate scenarios of the regime "
                     "twin, the frames extrapolated from the camera's motion; rates=oracle, "
                     "frames=persistence|oracle for the ablations), restore:POLICY (POLICY's "
                     "decisions, then archived keyframes brought back where the camera's "
                     "motion leads; with --archive-keyframes), reference (a clairvoyant search "
                     "started from every other listed policy: beam search, then swap local "
                     "search; not a bound; with an archive it restores with the future known)")
    add_setting_arguments(sim)
    sim.add_argument("--slot-frames", type=int, default=Comparison.slot_frames,
                     help="F, frames per slot (a slot lasts F / 30 Hz)")
    sim.add_argument("--d-req", type=float, default=Comparison.d_req_s, metavar="SECONDS",
                     help="D_req, the seconds a slot's uploads may take (Theorem 1 sizes U_k "
                     "by it; the first D_req of the next slot is tracked on the map before "
                     "the update)")
    sim.add_argument("--slots", type=int, default=Comparison.slots, help="slots per run")
    sim.add_argument("--seeds", type=int, default=Comparison.seeds,
                     help="runs per policy, seeds --seed0 … --seed0 + N - 1 (each seed: its "
                     "own start frame and rate sequence)")
    sim.add_argument("--seed0", type=int, default=Comparison.seed0, help="the first run's seed")
    sim.add_argument("--walk-start", type=int, default=None, metavar="FRAME",
                     help="every run starts at this frame of the covisibility and reads it "
                     "forward then back (0: the live player's forward_backward walk); default: "
                     "a random frame per seed")
    sim.add_argument("--paper-rule", action="store_true",
                     help="score as the paper does: a frame is lost only when it shares no map "
                     "point, the map update there at the slot's first frame, and |U_k| is "
                     "Theorem 1's exactly (default: the device's rule, twinslam/slot_protocol/"
                     "lost_frame_rule.py, and one upload a slot where the uplink carries one "
                     "within the slot but not within D_req)")
    sim.add_argument("--archive-keyframes", type=int, default=0, metavar="N",
                     help="the edge keeps up to N evicted keyframes (the least recently useful "
                     "leave first) instead of forgetting them; 0 (default): the paper's edge")
    sim.add_argument("--restore-keyframes", type=int, default=0, metavar="N",
                     help="archived keyframes a policy may bring back a slot (restore:POLICY, "
                     "mpc and the reference do; needs --archive-keyframes)")
    sim.add_argument("--csv", metavar="FILE",
                     help="also write one row per run: policy, spec (as given: tells two "
                     "checkpoints apart), seed, mean_uncertainty (a lost frame = 0), lost_share, "
                     "tracked_uncertainty")
    fleet = sim.add_argument_group(
        "one edge, many devices", "--devices N: N devices (each its own walk and uplink) "
        "inside one keyframe budget, one row per allocator, paired by seed against equal")
    fleet.add_argument("--devices", type=int, default=0, metavar="N",
                       help="devices sharing one edge's budget (0: one device, as above)")
    fleet.add_argument("--vmax-total", type=int, default=0, metavar="V",
                       help="V_total, keyframes of every map together (0: --vmax x N)")
    fleet.add_argument("--allocator", default="equal,motion,twin",
                       help="comma-separated: equal, motion (by novelty), twin (by the tracked "
                       "share a keyframe buys, with each device's regime twin); default "
                       "%(default)s")
    fleet.add_argument("--min-keyframes", type=int, default=5,
                       help="the least share a device gets; default %(default)s")
    fleet.add_argument("--fairness", type=float, default=0.0,
                       help="alpha of the twin allocator's alpha-fair sum (0: total, 1: "
                       "proportional fairness); default %(default)s")
    fleet.add_argument("--speeds", default="",
                       help="walking speeds the devices cycle through, comma-separated: 1 as "
                       "recorded, 2 twice as fast, 0.5 half as fast, 0 standing still")
    fleet.add_argument("--device-rates", default="",
                       help="uplink rate ranges the devices cycle through, MIN-MAX Mbit/s "
                       "comma-separated (e.g. 5-20,40-80); default: --rate-range for all")
    fleet.add_argument("--cell-capacity", type=float, default=0.0, metavar="MBPS",
                       help="the devices' uplinks share one cell of this many Mbit/s, each "
                       "getting its link rate x min(1, capacity / their sum); 0: no cell")
    fleet.add_argument("--cell-split", default="proportional",
                       choices=("proportional", "allocator"),
                       help="how --cell-capacity is shared: proportional to each link's rate, "
                       "or by the allocator (equal; motion: novelty; twin: the frames its map "
                       "would not track), each at most its link; default %(default)s")
    add_executor_arguments(sim, "seed")
    sim.add_argument("-v", "--verbose", action="store_true",
                     help="print every seed's scores as it finishes (without: its progress "
                     "line alone)")
    sim.set_defaults(func=run)
