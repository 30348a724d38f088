"""``twinslam evaluate``: the live pipeline per scenario x map source x policy x seed."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from twinslam.cli.arguments import (
    BUNDLED_SEQUENCE,
    FALLBACK_SEQUENCE,
    add_executor_arguments,
    add_pace_argument,
    open_executor,
)
from twinslam.cli.console import Subparsers, error
from twinslam.live import runs, tables
from twinslam.live.calibration.frames import covisibility_file
from twinslam.live.launcher import DEFAULT_PARAMS, player_camera
from twinslam.live.run_checks import params_file_problem, policy_problem
from twinslam.live.scenarios import SCENARIOS, Scenario, scenario
from twinslam.sequence_player.playback import Playback, PlayedSequence
from twinslam.sequences.frame import SequenceError
from twinslam.sequences.opening import open_sequence
from twinslam.slam.front_end.map_source import DEFAULT_MAP_SOURCE, MAP_SOURCES, check_map_source
from twinslam.uplink.families import FAMILIES

#: the fastest camera a run asks for, x the recorded rate (the player's own bound)
MAX_RATE = 1000.0


def _checked(args: argparse.Namespace) -> tuple[list[tuple[str, str]], list[Scenario], list[str]]:
    """The policies, scenarios and map sources asked for; ValueError (or SequenceError) names
    a bad option now, not in run 20."""
    sources = [m.strip() for m in args.map_source.split(",") if m.strip()]
    policies = runs.policy_variants(args.policy)
    scenarios = [scenario(n.strip()) for n in args.scenario.split(",") if n.strip()]
    for source in sources:
        reason = check_map_source(source)
        if reason:
            raise ValueError(f"--map-source: {reason}")
    for _, policy in policies:
        problem = policy_problem(policy)
        if problem:
            raise ValueError(f"--policy: {problem}")
    problem = params_file_problem(args.params)
    if problem:
        raise ValueError(f"--params: {problem}")
    if not 0 < args.rate <= MAX_RATE:
        raise ValueError(f"--rate must be above 0 and at most {MAX_RATE:g}, got {args.rate:g}")
    jobs = 1 if args.jobs is None else args.jobs
    for name, value, least in (("--seeds", args.seeds, 1), ("--jobs", jobs, 1),
                               ("--first-seed", args.first_seed, 0),
                               ("--frames", args.frames, 2), ("--start", args.start, 0)):
        if value < least:
            raise ValueError(f"{name} must be >= {least}, got {value}")
    opened = open_sequence(runs.sequence_for(args.sequence, 0), args.start,
                           args.start + args.frames)
    if len(opened) < args.frames:          # a run would play fewer than the table says
        raise ValueError(f"--frames {args.frames} from frame {args.start}: {args.sequence} "
                         f"has {len(opened)} frames there")
    for s in {s.order: s for s in scenarios}.values():
        PlayedSequence(opened, Playback(s.order))
    if not policies or not scenarios or not sources:
        raise ValueError("at least one policy, scenario and map source")
    return policies, scenarios, sources


def _where(args: argparse.Namespace) -> str:
    if args.executor == "ray":
        return f"on Ray ({args.ray_address or 'started here'})"
    return f"{args.jobs or 1} at a time"


def _tasks(args: argparse.Namespace, policies: list[tuple[str, str]],
           scenarios: list[Scenario], sources: list[str]) -> list[runs.RunTask]:
    """Every run, seed by seed (so the runs a paired comparison pairs share the machine's
    state), each still to do with the covisibility of the frames it plays (extracted once a
    sequence)."""
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    keys = [runs.RunKey(s.name, m, label, seed, "" if spec == label else spec)
            for s in scenarios for seed in seeds for m in sources for label, spec in policies]
    print(f"live evaluation: {len(keys)} runs ({len(scenarios)} scenarios x {len(sources)} map "
          f"sources x {len(policies)} policies x {len(seeds)} seeds) of {args.frames} frames "
          f"of {args.sequence} from frame {args.start}, {_where(args)}; results in "
          f"{args.out}", flush=True)
    # the simulator's view of every frame a run still to do plays (a resumed evaluation whose
    # runs are all in runs.csv extracts nothing: it only prints the tables)
    done = runs.finished_runs(args.out) if args.resume else {}
    covis: dict[str, Path] = {}
    for key in keys:
        sequence = runs.sequence_for(args.sequence, key.seed)
        if key not in done and sequence not in covis:
            covis[sequence] = covisibility_file(sequence, args.frames, args.out / "covis",
                                                lambda line: print(line, flush=True),
                                                args.start, player_camera(args.params))
    by_name = {s.name: s for s in scenarios}
    return [runs.RunTask(k, runs.sequence_for(args.sequence, k.seed), args.frames,
                         by_name[k.scenario], args.params, args.timeout,
                         covis.get(runs.sequence_for(args.sequence, k.seed)), args.verbose,
                         args.start, args.out / "runs" / f"{k.file_stem}.png",
                         rate=args.rate, pace_frames=args.pace)
            for k in keys]


def _print_failure_causes(out: Path) -> None:
    """Where the device's failed frames came from, per policy (nothing where no frame was
    calibrated: a run without a dataset, or a folder resumed from an older version)."""
    from twinslam.live.calibration.report import (
        failure_causes,
        failure_causes_markdown,
        read_rows,
    )
    try:
        causes = failure_causes(read_rows([out], "calibration_frames.csv"))
    except (FileNotFoundError, ValueError) as exc:
        print(f"\nno failure causes: {exc}")
        return
    if causes:
        print("\nwhere the device's failed next-slot frames come from (share of the scored "
              "frames, count; twinslam calibrate tells more):")
        print(failure_causes_markdown(causes))


def _print_tables(results: list[runs.RunResult], out: Path) -> None:
    rows = tables.summarise(results)
    notes = [n for n in (tables.dropped_frames_note(results),
                         tables.skipped_frames_note(results)) if n]
    tables.write_summary(rows, out, " ".join(notes) or None)
    paired = tables.paired_differences(results)
    tables.write_paired(paired, out)
    print()
    print(tables.markdown_table(rows))
    if paired:
        print("\npaired with the best rule policy, seed by seed (mean ± 95 % CI):")
        print(tables.paired_markdown(paired))
    for source, (r, n) in tables.agreement_over_runs(results).items():
        print(f"{source}: predicted lost share vs device failure share over {n} runs: "
              f"Pearson r = {r:.2f}")
    _print_failure_causes(out)
    print(f"\nwrote {out / 'runs.csv'}, summary.csv, summary.md, summary.png, "
          "paired.csv, paired.md, calibration.csv, calibration_frames.csv and a picture and "
          f"the nodes' logs of every run in {out / 'runs'}/")
    for note in notes:          # last, where a reader of the tables looks for what went wrong
        print(f"warning: {note}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    try:
        policies, scenarios, sources = _checked(args)
    except (ValueError, SequenceError) as exc:
        return error(exc)
    try:
        with open_executor(args) as executor:    # an unreachable Ray fails before any work
            tasks = _tasks(args, policies, scenarios, sources)
            results, failures = runs.run_all(tasks, args.out, executor,
                                             lambda line: print(line, flush=True), args.resume)
    except KeyboardInterrupt:
        print(f"interrupted: the runs that finished are in {args.out / 'runs.csv'} "
              "(the same command with --resume runs the rest)", file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        return error(exc, 1)
    if not results:
        return error(f"every run failed (tracebacks in {args.out / 'failures.txt'})", 1)
    _print_tables(results, args.out)
    if failures:
        return error(f"{len(failures)} of {len(tasks)} runs failed (tracebacks in "
                     f"{args.out / 'failures.txt'}); the tables hold the others", 1)
    return 0


def add_arguments(parser: argparse.ArgumentParser, default_sequence: str,
                  default_params: Path, scenario_names: list[str]) -> None:
    parser.add_argument("--sequence", default=default_sequence,
                        help="SUN3D / 7-Scenes / TUM folder, MCAP bag (forward only), or "
                        "synthetic[:frames] (the room) / synthetic-corridor[:frames] (each "
                        "seed walks its own path); default: "
                        "%(default)s")
    parser.add_argument("--frames", type=int, default=300,
                        help="frames of the sequence per run (revisit scenarios play them "
                        "forward then back: 2x-1); default %(default)s")
    parser.add_argument("--start", type=int, default=0,
                        help="the sequence's first frame played (e.g. keep a stretch for "
                        "tuning apart from the one evaluated); default %(default)s")
    parser.add_argument("--policy", default="lff,pu,adapt",
                        help="comma-separated: lff, pu, adapt, random, mbrl:CHECKPOINT, "
                        "mpc[:H=2/S=4/...] (the causal planner, '/' between its options), "
                        "delay:SECONDS:POLICY (POLICY's decisions handed back SECONDS late: "
                        "what deciding slowly costs), each optionally LABEL=POLICY (several "
                        "checkpoints under one label: one variant over its training runs); "
                        "default %(default)s")
    parser.add_argument("--scenario", default=",".join(scenario_names),
                        help="comma-separated, of: " + ", ".join(scenario_names)
                        + "; NAME@FAMILY runs it over an uplink family (" + ", ".join(FAMILIES)
                        + "; twinslam trace family NAME describes one); default all")
    parser.add_argument("--map-source", default=DEFAULT_MAP_SOURCE,
                        help="the device's map source(s), comma-separated, of: "
                        + ", ".join(MAP_SOURCES) + " (edge: the paper's device, tracked only "
                        "against the edge's map; edge+local: plus its own recent points); "
                        "default %(default)s, the product's default, as twinslam launch's")
    parser.add_argument("--seeds", type=int, default=3,
                        help="runs per scenario, map source and policy; default %(default)s")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="seeds are FIRST..FIRST+SEEDS-1 (keep tuning seeds apart from "
                        "evaluation seeds); default %(default)s")
    add_executor_arguments(parser, "run (each on a loopback domain of its own, about one "
                           "core)")
    parser.add_argument("--params", type=Path, default=default_params,
                        help="ROS 2 parameter file for the nodes; default %(default)s (the "
                        "default device's edge and slots); config/paper-table1.yaml with "
                        "--map-source edge: the paper's Table I device")
    parser.add_argument("--out", type=Path, default=Path("results/live"),
                        help="folder for runs.csv, summary.csv/.md/.png, runs/*.png and runs/*.log "
                        "(a picture and the nodes' logs of every run), calibration.csv, "
                        "calibration_frames.csv (and covis/, the played frames' "
                        "covisibility); default %(default)s")
    parser.add_argument("--resume", action="store_true",
                        help="keep the runs --out already holds (an interrupted evaluation) "
                        "and run only the missing ones; the tables cover both. Refused where "
                        "those runs were made under other settings (--frames, --start, "
                        "--rate, --params or its contents: --out/run_settings.json has them)")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="the cameras' speed, x the recorded frame rate, as twinslam "
                        "launch's: the run slows with them (its stamps follow the clock, a "
                        "slot of the device's frames lasts 1/RATE as long, recovery times "
                        "stretch alike); below 1 where the device cannot track in real time "
                        "beside what else the machine runs — a device that drops camera "
                        "frames measures the load (the tables warn of it); default "
                        "%(default)s")
    add_pace_argument(parser)
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds one run may take before its nodes are stopped; default "
                        "%(default)s")
    parser.add_argument("--verbose", action="store_true",
                        help="print every slot's status line, not only one line per run")


def register(sub: Subparsers) -> None:
    evaluate = sub.add_parser(
        "evaluate", help="the live pipeline per scenario x policy x seed: ATE, RPE, tracking "
        "failures, relocalisations, υ, uploads (CSV, table, plot)")
    add_arguments(evaluate, str(BUNDLED_SEQUENCE) if BUNDLED_SEQUENCE.is_dir() else
                  f"{FALLBACK_SEQUENCE}:300", DEFAULT_PARAMS, list(SCENARIOS))
    evaluate.set_defaults(func=run)
