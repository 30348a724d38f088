"""``twinslam``: the command-line entry point for the offline tools and the live pipeline.

    twinslam sim --covis FILE --policy lff,pu,adapt,reference [--channel markov:N=2]
                 [--vmax 45] [--slots 200] [--seeds 5] [--csv OUT]   # mbrl:CHECKPOINT too
    twinslam train --covis FILE --channel markov:N=2 --vmax 45 [--rate-model regime] -o OUT.pt
    twinslam extract SEQUENCE -o covis.npz [--start N] [--end N] [--features 1000]
    twinslam record SEQUENCE -o BAG [--start N] [--end N]   # the player's topics as MCAP
    twinslam trace generate -o uplink.csv --outage 300:10   # or: trace info FILE
    twinslam nodes [--timeout 3.5]        # the ROS graph on $ROS_DOMAIN_ID (ros2 node list)
    twinslam launch --scenario revisit-lost --policy lff,adapt --loopback
    twinslam evaluate --policy lff,pu,adapt --seeds 3     # live: policy x scenario x seed
    twinslam experiment fig7 --policy UDT=results/amm_udt.pt   # paper figures
    twinslam demo                         # what `make run` runs

`twinslam COMMAND --help` documents every option of a command.
"""

from __future__ import annotations

import argparse
import csv
import functools
import os
import sys
import time
from pathlib import Path

import numpy as np

from twinslam.common import table1
from twinslam.node_hosts.fastdds import REPO_ROOT
from twinslam.node_hosts.loopback import LoopbackDomain, ProcessDomain
from twinslam.simulator.covisibility import CovisibilityError, load_covisibility
from twinslam.simulator.env import SimConfig
from twinslam.uplink.channels import SLOT_SECONDS, ChannelError


class _EnvDomain(LoopbackDomain):
    """The domain of the environment ($ROS_DOMAIN_ID, discovery range, static peers) as it is,
    with the project's Fast DDS profile unless $FASTRTPS_DEFAULT_PROFILES_FILE names one."""

    def __init__(self) -> None:
        from twinslam.node_hosts.fastdds import domain_id_from_env

        super().__init__(domain_id_from_env())

    @property
    def env(self) -> dict[str, str]:
        from twinslam.node_hosts.fastdds import installed_profile

        env = self.base_env()
        env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(installed_profile()))
        return env


def _covis(spec: str):
    """``FILE[@START:END]`` (a stretch of a covisibility file's frames) or
    ``geometric[:FRAMES[:SEED]]`` (the room model; each seed walks its own trajectory)."""
    if spec.startswith("geometric"):
        from twinslam.simulator.geometric_covisibility import geometric_covisibility

        parts = spec.split(":")[1:]
        try:
            frames = int(parts[0]) if parts and parts[0] else 600
            seed = int(parts[1]) if len(parts) > 1 else 0
        except ValueError:
            raise CovisibilityError(f"--covis {spec!r}: use geometric[:FRAMES[:SEED]]") from None
        return geometric_covisibility(n_frames=frames, seed=seed)
    path, at, stretch = spec.partition("@")
    data = load_covisibility(Path(path))
    if not at:
        return data
    start, colon, end = stretch.partition(":")
    try:
        if not colon:
            raise ValueError
        return data.stretch(int(start or 0), int(end) if end else data.n_frames)
    except ValueError as exc:
        if isinstance(exc, CovisibilityError):
            raise
        raise CovisibilityError(f"--covis {spec!r}: use FILE@START:END (frame indices)") from None


def _rate_range(text: str) -> tuple[float, float]:
    """``--rate-range`` of sim and train: 'min,max' in Mbit/s."""
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'min,max', got {text!r}") from None
    return lo, hi


def cmd_sim(args: argparse.Namespace) -> int:
    from twinslam.policy_registry import make_policy
    from twinslam.simulator.evaluation import evaluate

    try:
        dataset = _covis(args.covis)
        rule = dict(min_shared=1, update_lag_frames=0) if args.paper_rule else {}
        config = SimConfig(vmax=args.vmax, slot_frames=args.slot_frames, slots=args.slots,
                           start=args.walk_start, **rule)
        policies = [p.strip() for p in args.policy.split(",") if p.strip()]
        seeds = list(range(args.seed0, args.seed0 + args.seeds))
        print(f"covisibility: {dataset.n_frames} frames ({dataset.source or args.covis}); "
              f"channel {args.channel}; V_max {args.vmax}, F {args.slot_frames}, "
              f"{args.slots} slots x {len(seeds)} seeds", flush=True)
        start = time.monotonic()
        report = (lambda m: print(f"  {m}", flush=True)) if args.verbose else None
        results = evaluate(policies, dataset, args.channel, config, seeds,
                           args.rate_range, progress=report, make_policy=make_policy)
    except (ChannelError, CovisibilityError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    reference = next((r for r in results if r.policy == "reference"), None)
    width = max(12, *(len(r.policy) for r in results))
    print(f"\n{'policy':<{width}} {'mean υ':>11} {'± ci95':>9} {'lost %':>7} {'υ tracked':>11}"
          f"{'  gap to reference' if reference else ''}")
    for r in results:
        gap = f"  {r.mean - reference.mean:+.2f}" if reference else ""
        print(f"{r.policy:<{width}} {r.mean:>11.2f} {r.ci95:>9.2f} {100 * r.lost_ratio:>7.2f} "
              f"{r.mean_tracked:>11.2f}{gap}")
    rule = ("the paper's rule: lost when no map point is shared" if args.paper_rule else
            f"lost with fewer than {config.min_shared} shared map points, a slot's first "
            f"{config.lag_frames} frames on the map before the last update")
    print(f"({time.monotonic() - start:.1f} s; {rule}; mean υ scores a lost frame as u = 0, a "
          "frame with no map; 'υ tracked' averages the tracked frames; mean υ = (1 - lost) · "
          "υ tracked. The reference is a clairvoyant search, not a bound)")
    if args.csv:
        with open(args.csv, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(["policy", "spec", "seed", "mean_uncertainty", "lost_share",
                             "tracked_uncertainty"])
            for spec, r in zip(policies, results, strict=True):
                for run in r.runs:
                    writer.writerow([r.policy, spec, run.seed, f"{run.mean_uncertainty:.6f}",
                                     f"{run.lost_share:.6f}", f"{run.tracked_uncertainty:.6f}"])
        print(f"wrote {args.csv} (one row per run)")
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    from twinslam.sequences.frame import SequenceError
    from twinslam.sequences.opening import open_sequence
    from twinslam.simulator.covisibility import save_covisibility
    from twinslam.simulator.extraction import extract_covisibility
    from twinslam.slam.tracking import TrackingConfig

    out = Path(args.output)
    if not out.parent.is_dir():
        print(f"error: output folder {out.parent} does not exist", file=sys.stderr)
        return 2
    try:
        reader = open_sequence(args.sequence, args.start, args.end)
    except SequenceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"extracting {len(reader)} frames of {reader.kind} sequence {reader.path}", flush=True)

    tty = sys.stdout.isatty()

    def progress(done: int, total: int) -> None:
        if tty and (done == total or done % 10 == 0):
            print(f"\r  {done}/{total} frames", end="\n" if done == total else "",
                  flush=True)
        elif not tty and (done == total or done % 100 == 0):
            print(f"  {done}/{total} frames", flush=True)

    try:
        dataset, _, report = extract_covisibility(
            reader, TrackingConfig(n_features=args.features), progress)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    save_covisibility(out, dataset)
    sizes = np.diff(dataset.point_offsets)
    print(f"wrote {out}: {report.frames} frames, {report.map_points} map points, "
          f"{sizes.mean():.0f} observed per frame, {report.keyframes} keyframes, "
          f"{report.untracked} untracked, {len(report.skipped)} skipped files; "
          f"front end {np.median(report.frontend_ms):.1f} ms/frame median, "
          f"{report.seconds:.1f} s in all")
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from twinslam.sequence_player.recording import record_bag
    from twinslam.sequences.frame import SequenceError
    from twinslam.sequences.opening import open_sequence

    try:
        reader = open_sequence(args.sequence, args.start, args.end)
        print(f"recording {len(reader)} frames of {reader.kind} sequence {reader.path} to "
              f"{args.output} (rosbag2, MCAP)", flush=True)
        written = record_bag(reader, args.output)
    except SequenceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {written} frames, {len(reader.skipped)} skipped"
          f"{': ' + ', '.join(reader.skipped) if reader.skipped else ''}")
    return 0


def cmd_nodes(args: argparse.Namespace) -> int:
    """The ROS graph's nodes on $ROS_DOMAIN_ID, as ``ros2 node list`` prints them."""
    from twinslam.node_hosts.fastdds import domain_id_from_env
    from twinslam.node_hosts.session import RosSession

    try:
        domain_id_from_env()
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    session = RosSession("twinslam_nodes")
    try:
        session.spin_until(lambda: False, args.timeout)     # let discovery run
        names = sorted(f"{ns.rstrip('/')}/{name}" for name, ns in
                       session.node.get_node_names_and_namespaces()
                       if name != "twinslam_nodes")
    finally:
        session.close()
    for name in names:
        print(name)
    return 0


def cmd_hosts(args: argparse.Namespace) -> int:
    """Build or remove the three test hosts (network namespaces) and say how to use them."""
    from twinslam.node_hosts.netns import (
        HOST_PROFILE,
        HOSTS,
        NetnsError,
        NetnsHosts,
        address_of,
        unavailable_reason,
    )

    hosts = NetnsHosts(prefix=args.prefix)
    if args.action == "down":
        hosts.down()
        left = hosts.exists()
        print("removed" if not left else f"could not remove {', '.join(left)}")
        return 0 if not left else 1
    if args.action == "config":
        print(HOST_PROFILE)
        return 0
    why = unavailable_reason()
    if why:
        print(f"twinslam hosts: {why}", file=sys.stderr)
        return 2
    try:
        hosts.up()
    except NetnsError as exc:
        print(f"twinslam hosts: {exc}", file=sys.stderr)
        return 1
    for host in HOSTS:
        print(f"{host:<7} netns {hosts.namespaces[host]:<20} eth0 {address_of(host)}/24")
    peers = ";".join(address_of(h) for h in HOSTS)
    print("\nrun a node on a host, e.g.:\n"
          "  twinslam hosts config > /tmp/fastdds_host.xml\n"
          "  export FASTRTPS_DEFAULT_PROFILES_FILE=/tmp/fastdds_host.xml "
          f"ROS_STATIC_PEERS='{peers}'\n"
          f"  ip netns exec {hosts.namespaces['edge']} .venv/bin/python -m edge_mapper.node\n"
          f"shape the device's uplink: ip netns exec {hosts.namespaces['device']} "
          "tc qdisc replace dev eth0 root tbf rate 40mbit burst 64kb latency 500ms "
          "(or device_tracker -p shaper:=tc)")
    return 0


def _launch_domain(args: argparse.Namespace) -> ProcessDomain:
    """Where ``twinslam launch`` runs the nodes: three namespaces, loopback, or $ROS_DOMAIN_ID."""
    if args.hosts:
        from twinslam.node_hosts.netns import NetnsHosts

        return NetnsHosts(prefix=f"twinslam{os.getpid()}-")
    return LoopbackDomain() if args.loopback else _EnvDomain()


def _real_frame_uplink(sequence: str) -> dict[str, list[str]]:
    """tc-shaped uplink parameters whose α is the sequence's first colour image as rgb8."""
    from twinslam.cli.launcher import tc_uplink_params
    from twinslam.sequences.opening import open_sequence

    first = next(iter(open_sequence(sequence, 0, 1)))
    return tc_uplink_params(first.color.nbytes * 8 / 1e6)


def cmd_launch(args: argparse.Namespace) -> int:
    from twinslam.cli.launcher import LaunchConfig, Launcher, print_table
    from twinslam.policy_registry import LEARNED_PREFIX

    if not args.params.is_file():
        print(f"error: parameter file {args.params} does not exist", file=sys.stderr)
        return 2
    extra: dict[str, list[str]] = {}
    if args.tc:
        if not args.hosts:
            print("error: --tc shapes the device host's uplink: use it with --hosts",
                  file=sys.stderr)
            return 2
        extra = _real_frame_uplink(args.sequence)
    if args.hosts:
        from twinslam.node_hosts.netns import unavailable_reason

        why = unavailable_reason()
        if why:
            print(f"error: --hosts: {why}", file=sys.stderr)
            return 2
    from twinslam.cli.scenarios import scenario

    try:
        chosen = scenario(args.scenario)
    except ValueError as exc:
        print(f"error: --scenario: {exc}", file=sys.stderr)
        return 2
    if args.map_source is not None:
        from twinslam.slam.map_source import check_map_source

        reason = check_map_source(args.map_source)
        if reason:
            print(f"error: --map-source: {reason}", file=sys.stderr)
            return 2
        extra.setdefault("device_tracker", []).append(f"map_source:={args.map_source}")
    reports = []
    for policy in [p.strip() for p in args.policy.split(",") if p.strip()]:
        # a learned policy decides on the twin node's latents: start it with its checkpoint
        kind, _, checkpoint = policy.partition(":")
        learned = kind == LEARNED_PREFIX and bool(checkpoint)
        run_extra = {**extra, **({"udt_node": [f"policy_checkpoint:={checkpoint}"]}
                                 if learned else {})}
        config = LaunchConfig(args.sequence, policy, args.frames, args.rate, args.params,
                              with_twin=args.twin or learned, timeout_s=args.timeout,
                              extra=run_extra, scenario=chosen, start=args.start)
        with _launch_domain(args) as dom:
            if args.loopback:
                dom.activate()
            where = ("hosts device/edge/twin, domain" if args.hosts else
                     "loopback domain" if args.loopback else "domain")
            print(f"{policy}: {args.frames} frames of {args.sequence} at {args.rate}x on "
                  f"{where} {dom.domain_id}", flush=True)
            try:
                reports.append(Launcher(dom, config,
                                        lambda line: print(line, flush=True)).run())
            except KeyboardInterrupt:
                print("interrupted: nodes stopped", file=sys.stderr)
                return 130
            except RuntimeError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 1
    print()
    print_table(reports)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from twinslam.cli import evaluate as ev
    from twinslam.cli.live_calibration import covisibility_file
    from twinslam.cli.scenarios import scenario
    from twinslam.sequence_player.playback import Playback, PlayedSequence
    from twinslam.sequences.frame import SequenceError
    from twinslam.sequences.opening import open_sequence
    from twinslam.slam.map_source import check_map_source

    sources = [m.strip() for m in args.map_source.split(",") if m.strip()]
    try:
        policies = ev.policy_variants(args.policy)
        scenarios = [scenario(n.strip()) for n in args.scenario.split(",") if n.strip()]
        for source in sources:
            reason = check_map_source(source)
            if reason:
                raise ValueError(f"--map-source: {reason}")
        for _, policy in policies:
            kind, _, path = policy.partition(":")
            if kind == "mbrl" and not Path(path).is_file():
                raise ValueError(f"{path}: no such policy checkpoint (`twinslam train`)")
        if not args.params.is_file():
            raise ValueError(f"parameter file {args.params} does not exist")
        for name, value, least in (("--seeds", args.seeds, 1), ("--jobs", args.jobs, 1),
                                   ("--first-seed", args.first_seed, 0),
                                   ("--frames", args.frames, 2), ("--start", args.start, 0)):
            if value < least:
                raise ValueError(f"{name} must be >= {least}, got {value}")
        for s in {s.order: s for s in scenarios}.values():     # fails now, not in run 20
            PlayedSequence(open_sequence(ev.sequence_for(args.sequence, 0), args.start,
                                         args.start + args.frames), Playback(s.order))
    except (ValueError, SequenceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not policies or not scenarios or not sources:
        print("error: at least one policy, scenario and map source", file=sys.stderr)
        return 2
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    # seed by seed, so the runs a paired comparison pairs share the machine's state
    keys = [ev.RunKey(s.name, m, label, seed, "" if spec == label else spec)
            for s in scenarios for seed in seeds for m in sources for label, spec in policies]
    print(f"live evaluation: {len(keys)} runs ({len(scenarios)} scenarios x {len(sources)} map "
          f"sources x {len(policies)} policies x {len(seeds)} seeds) of {args.frames} frames "
          f"of {args.sequence} from frame {args.start}, {args.jobs} at a time; results in "
          f"{args.out}", flush=True)
    covis: dict[str, Path] = {}
    try:
        for seed in seeds:                  # the simulator's view of every played frame
            sequence = ev.sequence_for(args.sequence, seed)
            if sequence not in covis:
                covis[sequence] = covisibility_file(sequence, args.frames, args.out / "covis",
                                                    lambda line: print(line, flush=True),
                                                    args.start)
        by_name = {s.name: s for s in scenarios}
        tasks = [ev.RunTask(k, ev.sequence_for(args.sequence, k.seed), args.frames,
                            by_name[k.scenario], args.params, args.timeout,
                            covis[ev.sequence_for(args.sequence, k.seed)], args.verbose,
                            args.start)
                 for k in keys]
        results, failures = ev.run_all(tasks, args.out, args.jobs,
                                       lambda line: print(line, flush=True), args.resume)
    except KeyboardInterrupt:
        print(f"interrupted: the runs that finished are in {args.out / 'runs.csv'} "
              "(the same command with --resume runs the rest)", file=sys.stderr)
        return 130
    except (RuntimeError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if not results:
        print(f"error: every run failed (tracebacks in {args.out / 'failures.txt'})",
              file=sys.stderr)
        return 1
    rows = ev.summarise(results)
    ev.write_summary(rows, args.out)
    paired = ev.paired_differences(results)
    ev.write_paired(paired, args.out)
    print()
    print(ev.markdown_table(rows))
    if paired:
        print("\npaired with the best rule policy, seed by seed (mean ± 95 % CI):")
        print(ev.paired_markdown(paired))
    for source, (r, n) in ev.agreement_over_runs(results).items():
        print(f"{source}: predicted lost share vs device failure share over {n} runs: "
              f"Pearson r = {r:.2f}")
    print(f"\nwrote {args.out / 'runs.csv'}, summary.csv, summary.md, summary.png, "
          "paired.csv, paired.md, calibration.csv, calibration_frames.csv")
    if failures:
        print(f"error: {len(failures)} of {len(tasks)} runs failed (tracebacks in "
              f"{args.out / 'failures.txt'}); the tables hold the others", file=sys.stderr)
        return 1
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from dataclasses import asdict, fields

    from twinslam.common.reporting import write_csv
    from twinslam.experiments.calibration_report import (
        ScenarioAgreement,
        agreement_by_scenario,
        agreement_markdown,
        calibrate_runs,
        plot_calibration,
        read_rows,
        report_lines,
    )

    try:
        runs = read_rows(args.folders, "calibration.csv")
        frames = read_rows(args.folders, "calibration_frames.csv")
        results = calibrate_runs(runs, frames)
        agreement = agreement_by_scenario(runs)
    except (FileNotFoundError, KeyError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not results:
        print("error: no calibrated next-slot frame in those folders", file=sys.stderr)
        return 2
    for line in report_lines(results):
        print(line)
    table = agreement_markdown(agreement)
    print("\nper map source and scenario (shares and measures: mean over runs):")
    print(table)
    out = args.out or args.folders[0] / "calibration.png"
    plot_calibration(runs, frames, results, out)
    write_csv(out.with_suffix(".csv"), [f.name for f in fields(ScenarioAgreement)],
              [list(asdict(a).values()) for a in agreement])
    out.with_suffix(".md").write_text(table + "\n", encoding="utf-8")
    print(f"wrote {out}, {out.with_suffix('.csv')} and {out.with_suffix('.md')}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from twinslam.cli.demo import run_demo

    return run_demo(args)


def _learned(specs: list[str]) -> dict[str, dict[str, list[Path]]]:
    """``LABEL=PATH`` or ``LABEL@N=PATH`` (fig8: the policy for N rate states) → {N or '':
    {label: [paths]}}; a label given more than once is one variant over several training
    runs. A missing file is an error now, not after an hour of other policies."""
    out: dict[str, dict[str, list[Path]]] = {}
    for spec in specs:
        label, sep, path = spec.partition("=")
        if not sep or not label or not path:
            raise ValueError(f"--policy takes LABEL=CHECKPOINT (e.g. UDT=results/udt.pt), "
                             f"got {spec!r}")
        label, _, n = label.partition("@")
        if not Path(path).is_file():
            raise ValueError(f"{path}: no such policy checkpoint (train one with "
                             "`twinslam train`)")
        out.setdefault(n, {}).setdefault(label, []).append(Path(path))
    return out


def cmd_amm_experiment(args: argparse.Namespace) -> int:
    from twinslam.experiments import amm as ex

    t0 = time.monotonic()

    def progress(line: str) -> None:
        print(f"[{time.monotonic() - t0:7.1f} s] {line}", file=sys.stderr, flush=True)

    try:
        learned = _learned(args.policy or [])
        dataset = _covis(args.covis)
    except (CovisibilityError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    setting = ex.Setting(runs=args.runs or 20, slots=args.slots or 200, seed0=args.seed,
                         reference_swaps=args.reference_swaps)
    out = Path(args.out)
    if args.name == "fig8":
        by_n = {int(n or 2): pol for n, pol in learned.items()}
        results = ex.fig8(dataset, by_n, out, setting, progress)
    else:
        fig = ex.fig7 if args.name == "fig7" else ex.fig9
        results = fig(dataset, learned.get("", {}), out, setting, progress=progress)
    for x, by in results.items():
        print(f"{x}: " + ", ".join(f"{label} {r.mean:.1f} ± {r.ci95:.1f}"
                                    for label, r in by.items()))
    print(f"wrote {out}/{args.name}.csv and .png ({time.monotonic() - t0:.0f} s)")
    return 0


def cmd_twin_predict(args: argparse.Namespace) -> int:
    from twinslam.experiments import twin_predict as ex
    from twinslam.twin.next_state import PredictionProtocol

    t0 = time.monotonic()

    def progress(line: str) -> None:
        print(f"[{time.monotonic() - t0:7.1f} s] {line}", file=sys.stderr, flush=True)

    sources = list(args.source or ex.DEFAULT_SOURCES)
    sources += [f"trace:{path}" for path in args.trace or []]
    try:
        protocol = PredictionProtocol(n_states=args.states or 4,
                                      retrain_every=args.retrain_every or 100,
                                      buffer_slots=args.buffer_slots or 600)
        from twinslam.twin.next_state import PREDICTORS, check_predictors

        predictors = (PREDICTORS if args.predictor == "all" else
                      tuple(p.strip() for p in args.predictor.split(",") if p.strip()))
        setting = ex.Setting(slots=args.slots or 3000, seeds=args.runs or 5, seed0=args.seed,
                             slot_seconds=args.slot_seconds, predictors=predictors,
                             protocol=protocol)
        check_predictors(predictors)
        for spec in sources:
            ex.check_source(spec, args.slot_seconds)
    except (ValueError, ChannelError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    summary = ex.twin_predict(sources, out, setting, progress, jobs=args.jobs)
    for source in dict.fromkeys(m.source for m in summary):
        print(f"{source}  (mean log p(next state) ± 95 % CI, nats; Brier; "
              f"minus the best counting estimator)")
        for m in summary:
            if m.source == source:
                print(f"  {m.predictor:>14} {m.log_likelihood[0]:8.4f} ± "
                      f"{m.log_likelihood[1]:.4f}  Brier {m.brier[0]:.4f}  "
                      f"{m.vs_counting[0]:+8.4f} ± {m.vs_counting[1]:.4f}")
    print(f"wrote {out}/twin_predict.csv, twin_predict_runs.csv and twin_predict.png "
          f"({time.monotonic() - t0:.0f} s)")
    return 0


def cmd_experiment(args: argparse.Namespace) -> int:
    if args.name in ("fig7", "fig8", "fig9"):
        return cmd_amm_experiment(args)
    if args.name == "twin-predict":
        return cmd_twin_predict(args)
    from twinslam.experiments import twin as ex

    out = Path(args.out)
    args.states = args.states or 2
    args.runs = args.runs or 20
    args.retrain_every = args.retrain_every or 300
    args.buffer_slots = args.buffer_slots or 300
    proto = ex.Protocol(interval_slots=args.interval_slots, retrain_every=args.retrain_every,
                        buffer_slots=args.buffer_slots)
    t0 = time.monotonic()

    def progress(line: str) -> None:
        print(f"[{time.monotonic() - t0:7.1f} s] {line}", file=sys.stderr, flush=True)

    if args.name == "udt-fig3":
        res = ex.fig3(out, seed=args.seed, progress=progress,
                      proto=ex.Protocol(interval_slots=max(args.interval_slots, 1000),
                                        retrain_every=args.retrain_every,
                                        buffer_slots=max(args.buffer_slots, 1000)))
        print(f"UDT error on a 4-state chain (mean |P̂ - P|): {res['error']:.4f}")
    elif args.name == "udt-fig4":
        res4 = ex.fig4(out, runs=args.runs, seed=args.seed, proto=proto, progress=progress,
                       jobs=args.jobs)
        print(f"{'N':>3} " + " ".join(f"{name:>16}" for name in res4))
        for n in next(iter(res4.values())):
            print(f"{n:>3} " + " ".join(f"{sum(v[n]) / len(v[n]):16.4f}" for v in res4.values()))
    else:
        res5 = ex.fig5(out, runs=args.runs, n_states=args.states, seed=args.seed, proto=proto,
                       progress=progress, jobs=args.jobs)
        for mode, by in res5.items():
            print(mode + ": " + ", ".join(f"{name} {v.mean():.4f}" for name, v in by.items()))
    print(f"wrote {out}/{args.name.replace('-', '_')}.csv and .png")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    import torch

    from twinslam.mbrl.trainer import AmmTrainer, TrainConfig

    try:
        dataset = _covis(args.covis)
        config = TrainConfig(channel=args.channel, rate_range=args.rate_range,
                             vmax=args.vmax, slots=args.slots, episode_slots=args.episode_slots,
                             seed=args.seed, rate_model=args.rate_model, actor=args.actor,
                             real_fraction=args.real_fraction,
                             artificial_per_real=args.artificial)
        torch.set_num_threads(args.threads)
        t0 = time.monotonic()

        def progress(line: str) -> None:
            print(f"[{time.monotonic() - t0:7.1f} s] {line}", file=sys.stderr, flush=True)

        trainer = AmmTrainer(config, dataset, progress)
    except (ChannelError, CovisibilityError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"training on {dataset.n_frames} frames ({dataset.source or args.covis}); channel "
          f"{args.channel}; V_max {args.vmax}; actor {args.actor}; rate model "
          f"{args.rate_model}; I/|Ξ| "
          f"{config.real_count}/{config.batch_size}, J {config.artificial_per_real}; "
          f"{args.slots} slots", flush=True)
    log = trainer.train()
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    trainer.save(out)
    log_path = out.with_suffix(".csv")
    log.write_csv(log_path)
    print(f"wrote {out} (use it as --policy mbrl:{out}) and the training log {log_path} "
          f"({time.monotonic() - t0:.0f} s)")
    return 0


def _outage(text: str) -> tuple[float, float]:
    """``--outage START:SECONDS`` of ``twinslam trace generate``."""
    start, sep, length = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(start), float(length)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be START:SECONDS, got {text!r}") from None


def cmd_trace(args: argparse.Namespace) -> int:
    """Generate a throughput trace, or describe one (what a trace channel will replay)."""
    from twinslam.uplink.channels import SLOT_SECONDS, TraceChannel
    from twinslam.uplink.traces import TraceShape, generate_trace, write_trace

    try:
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
        print(f"error: {exc}", file=sys.stderr)
        return 2
    slots = chan.slot_rates()
    print(f"{path}: {chan.duration_s:.1f} s, {slots.size} slots of {chan.slot_seconds:g} s; "
          f"per-slot Mbit/s min {slots.min():.1f}, median {np.median(slots):.1f}, max "
          f"{slots.max():.1f}; {np.mean(slots == 0):.1%} of slots down")
    print(f"{chan.n_states} states by the trace's quantiles: thresholds "
          f"{', '.join(f'{t:.1f}' for t in chan.quantiser.thresholds)} Mbit/s, representative "
          f"rates {', '.join(f'{r:.1f}' for r in chan.rates)}")
    return 0


def _add_setting_arguments(parser: argparse.ArgumentParser) -> None:
    """What the simulator and the trainer both take: the data, the uplink and V_max."""
    parser.add_argument("--covis", required=True, metavar="FILE[@START:END]|geometric[:N[:SEED]]",
                        help="covisibility .npz from `twinslam extract` (@START:END: only that "
                        "stretch of its frames, e.g. to hold the rest out), or "
                        "'geometric[:frames[:seed]]' for the geometric room model (600 frames, "
                        "seed 0 unless given; each seed walks its own trajectory)")
    parser.add_argument("--channel", default="markov:N=2",
                        help="uplink rate model (default %(default)s). "
                        "markov:N=2[,ratio=R][,K=100][,nonstationary][,balanced]: N rates evenly "
                        "over --rate-range; ratio=R: share of high-rate slots (N=2); K: slots "
                        "per interval; nonstationary: a new matrix every K slots; balanced: "
                        "every state equally often. trace:FILE[,N=4][,states=MIN-MAX][,rescale]"
                        "[,start=S][,slot=S]: a CSV throughput trace at its real Mbit/s (an "
                        "outage uploads nothing), states by the trace's quantiles or evenly "
                        "over states=, rescale: map its min..max onto --rate-range, start: "
                        "seconds into the trace for every seed (default: an offset per seed), "
                        "slot: seconds a slot lasts (default 2)")
    parser.add_argument("--rate-range", type=_rate_range, metavar="MIN,MAX",
                        default=f"{table1.RATE_MIN_MBPS:g},{table1.RATE_MAX_MBPS:g}",
                        help="Mbit/s the Markov channel's N rates spread over (a trace only "
                        "with its rescale option)")
    parser.add_argument("--vmax", type=int, default=table1.VMAX,
                        help="V_max, keyframes the edge map holds at most")


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every option's help ends with its default, unless the text already gives it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (action.option_strings and default is not None and default is not False
                and default != argparse.SUPPRESS and "default" not in text):
            text += " (default: %(default)s)"
        return text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="twinslam", description=__doc__,
                                     formatter_class=_HelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub.add_parser = functools.partial(sub.add_parser,  # type: ignore[method-assign]
                                       formatter_class=_HelpFormatter)
    sim = sub.add_parser("sim", help="evaluate map-management policies offline",
                         description="Each policy over --seeds runs of the gym-style simulator "
                         "(covisibility from real frames, a rate model): mean υ with a lost "
                         "frame scoring 0, its 95 %% CI, the lost share and υ over tracked "
                         "frames.")
    sim.add_argument("--policy", default="lff,pu,adapt,reference",
                     help="comma-separated: lff (latest frames first), pu (periodical "
                     "uploading), adapt (AdaptSLAM's greedy log-det), random, mbrl:CHECKPOINT "
                     "(a policy from `twinslam train`), reference (a clairvoyant search "
                     "started from every other listed policy: beam search, then swap local "
                     "search; not a bound)")
    _add_setting_arguments(sim)
    sim.add_argument("--slot-frames", type=int, default=table1.SLOT_FRAMES,
                     help="F, frames per slot (a slot lasts F / 30 Hz)")
    sim.add_argument("--slots", type=int, default=200, help="slots per run")
    sim.add_argument("--seeds", type=int, default=5,
                     help="runs per policy, seeds --seed0 … --seed0 + N - 1 (each seed: its "
                     "own start frame and rate sequence)")
    sim.add_argument("--seed0", type=int, default=0, help="the first run's seed")
    sim.add_argument("--walk-start", type=int, default=None, metavar="FRAME",
                     help="every run starts at this frame of the covisibility and reads it "
                     "forward then back (0: the live player's forward_backward walk); default: "
                     "a random frame per seed")
    sim.add_argument("--paper-rule", action="store_true",
                     help="score as the paper does: a frame is lost only when it shares no map "
                     "point, the map update there at the slot's first frame (default: the "
                     "device's rule, twinslam/common/tracking_rule.py)")
    sim.add_argument("--csv", metavar="FILE",
                     help="also write one row per run: policy, spec (as given: tells two "
                     "checkpoints apart), seed, mean_uncertainty (a lost frame = 0), lost_share, "
                     "tracked_uncertainty")
    sim.add_argument("-v", "--verbose", action="store_true",
                     help="print every run's scores as it finishes")
    sim.set_defaults(func=cmd_sim)
    train = sub.add_parser("train", help="train the learned (MBRL) map-management policy",
                           description="Actor-critic on the map graph (paper §VI), the state "
                           "augmented by a rate model; checkpoints are validated on seeds "
                           "training never plays and the best validation is kept. Writes the "
                           "checkpoint and a CSV training log beside it.")
    _add_setting_arguments(train)
    train.add_argument("--slots", type=int, default=3000, help="real slots to train on")
    train.add_argument("--episode-slots", type=int, default=200, help="slots per episode")
    train.add_argument("--rate-model", default="regime",
                       choices=["regime", "udt", "lstm", "markov"],
                       help="what augments the state and generates artificial experiences: "
                       "regime (the Bayesian regime twin's posterior; the best next-state "
                       "predictor measured, `experiment twin-predict`), udt (the variational "
                       "twin's latent, paper §V), lstm (a point predictor), markov "
                       "(transition counts)")
    train.add_argument("--actor", default="residual", choices=["paper", "residual"],
                       help="paper: the paper's AMM (the GCN's score per frame, no ADAPT "
                       "prior, no ADAPT features); residual: ADAPT + residual RL (ADAPT's "
                       "decision as prior and node features, plus a learned correction)")
    train.add_argument("--real-fraction", type=float, default=0.5,
                       help="I/|Ξ|: share of real tuples in each batch, in (0, 1], when "
                       "--artificial > 0")
    train.add_argument("--artificial", type=int, default=0,
                       help="J: artificial tuples per real one; 0 (default): real experiences "
                       "only — the blended replay helped at none of 300, 1000, 3000 real slots "
                       "(docs/results.md, issue #20); the paper's configuration is "
                       "--artificial 2 --real-fraction 0.5")
    train.add_argument("--seed", type=int, default=0, help="seed of the channel and the networks")
    train.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    train.add_argument("-o", "--output", default="results/amm_policy.pt", metavar="FILE",
                       help="checkpoint to write (then --policy mbrl:FILE)")
    train.set_defaults(func=cmd_train)
    extract = sub.add_parser("extract", help="covisibility dataset from an RGB-D sequence",
                             description="Runs the device's ORB front end and tracking over a "
                             "sequence and stores which map points every frame observes (the "
                             "simulator's and the trainer's --covis).")
    extract.add_argument("sequence", help="a SUN3D, 7-Scenes or TUM RGB-D folder, a recorded "
                         "bag, or synthetic[:frames]")
    extract.add_argument("-o", "--output", required=True, help="covisibility .npz to write")
    extract.add_argument("--start", type=int, default=0, help="index of the first frame read")
    extract.add_argument("--end", type=int, default=-1,
                         help="index of the first frame not read (-1: to the end)")
    extract.add_argument("--features", type=int, default=1000, help="ORB features per frame")
    extract.set_defaults(func=cmd_extract)
    record = sub.add_parser("record", help="a sequence's camera topics as a rosbag2 (MCAP)")
    record.add_argument("sequence", help="a SUN3D, 7-Scenes or TUM RGB-D folder")
    record.add_argument("-o", "--output", required=True, help="rosbag2 folder to create")
    record.add_argument("--start", type=int, default=0, help="index of the first frame recorded")
    record.add_argument("--end", type=int, default=-1,
                        help="index of the first frame not recorded (-1: to the end)")
    record.set_defaults(func=cmd_record)
    nodes = sub.add_parser("nodes", help="list the nodes on $ROS_DOMAIN_ID (like ros2 node list)")
    nodes.add_argument("--timeout", type=float, default=3.5,
                       help="seconds of discovery before listing (default 3.5: a node announces "
                       "itself every 3 s at Fast DDS's defaults, every 1 s with the project's "
                       "profile; a shorter wait can miss nodes)")
    nodes.set_defaults(func=cmd_nodes)
    hosts = sub.add_parser("hosts", help="device, edge and twin hosts as network namespaces "
                           "(root)")
    hosts.add_argument("action", choices=["up", "down", "config"],
                       help="build them, remove them, or print a host's Fast DDS profile")
    hosts.add_argument("--prefix", default="", help="namespace name prefix (default none: "
                       "device, edge, twin, switch)")
    hosts.set_defaults(func=cmd_hosts)
    launch = sub.add_parser("launch", help="run player, device, edge (and twin) as processes")
    launch.add_argument("--sequence", default="synthetic",
                        help="SUN3D / 7-Scenes / TUM folder, MCAP bag, or synthetic[:frames]")
    launch.add_argument("--policy", default="adapt",
                        help="the edge's policy, one run each, comma-separated: lff, pu, adapt, "
                        "random, mbrl:CHECKPOINT")
    launch.add_argument("--frames", type=int, default=600, help="frames to play; -1: all")
    launch.add_argument("--start", type=int, default=0,
                        help="the sequence's first frame played; default %(default)s")
    launch.add_argument("--rate", type=float, default=1.0,
                        help="playback speed, × the recorded frame rate")
    launch.add_argument("--params", type=Path, default=REPO_ROOT / "config" / "twinslam.yaml",
                        help="ROS 2 parameter file for the nodes")
    launch.add_argument("--twin", action="store_true",
                        help="start udt_node too (a learned policy's run always does, with "
                        "its checkpoint's twin)")
    launch.add_argument("--loopback", action="store_true",
                        help="a private loopback DDS domain instead of $ROS_DOMAIN_ID")
    launch.add_argument("--hosts", action="store_true",
                        help="device, edge and twin in network namespaces of their own (root)")
    launch.add_argument("--tc", action="store_true",
                        help="with --hosts: the device's uplink shaped by tc at d_k, keyframes "
                        "carrying their image")
    launch.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds a policy's run may take before its nodes are stopped")
    from twinslam.cli.scenarios import SCENARIOS

    launch.add_argument("--scenario", default="forward",
                        help="; ".join(f"{s.name}: {s.description}" for s in SCENARIOS.values()
                                       ).replace("%", "%%") + "; default %(default)s")
    launch.add_argument("--map-source", default=None,
                        help="the device's map source: edge (tracked only against the edge's "
                        "map, the paper's device) or edge+local (plus its own recent points); "
                        "default: the parameter file's")
    launch.set_defaults(func=cmd_launch)
    from twinslam.cli.demo import REAL_SEQUENCE
    from twinslam.cli.evaluate import add_arguments

    evaluate = sub.add_parser(
        "evaluate", help="the live pipeline per scenario x policy x seed: ATE, RPE, tracking "
        "failures, relocalisations, υ, uploads (CSV, table, plot)")
    add_arguments(evaluate, str(REAL_SEQUENCE) if REAL_SEQUENCE.is_dir() else "synthetic:300",
                  REPO_ROOT / "config" / "twinslam.yaml", list(SCENARIOS))
    evaluate.set_defaults(func=cmd_evaluate)
    calibrate = sub.add_parser(
        "calibrate", help="the rule of a lost frame, measured from `twinslam evaluate` runs: "
        "lag, threshold, agreement per run and per scenario (calibration.png, .csv, .md)")
    calibrate.add_argument("folders", nargs="+", type=Path,
                           help="output folders of `twinslam evaluate` (calibration.csv and "
                           "calibration_frames.csv in each)")
    calibrate.add_argument("--out", type=Path, default=None,
                           help="the figure to write, the table beside it as .csv and .md "
                           "(default: FIRST_FOLDER/calibration.png)")
    calibrate.set_defaults(func=cmd_calibrate)
    demo = sub.add_parser("demo", help="the live pipeline per policy with the paper's device "
                          "and the Edge-SLAM style one, then the simulator")
    demo.add_argument("--frames", type=int, default=300,
                      help="frames of the sequence the live runs play forward and back "
                      "(2x-1 played); default %(default)s")
    demo.add_argument("--slots", type=int, default=40, help="simulator slots per run")
    demo.add_argument("--seeds", type=int, default=3, help="simulator runs per policy")
    demo.set_defaults(func=cmd_demo)
    trace = sub.add_parser("trace", help="generate a synthetic uplink trace with regimes and "
                           "outages, or describe a trace file")
    trace.add_argument("action", choices=["generate", "info"],
                       help="generate: write a trace to -o; info: describe FILE as a trace "
                       "channel replays it (duration, per-slot rates, outages, states)")
    trace.add_argument("file", nargs="?", help="info: the trace CSV to describe")
    trace.add_argument("-o", "--output", help="generate: CSV to write (time_s,throughput_mbps)")
    trace.add_argument("--seconds", type=float, default=600.0,
                       help="generate: trace length in s (default %(default)s)")
    trace.add_argument("--sample", type=float, default=0.1,
                       help="generate: s between samples (default %(default)s)")
    trace.add_argument("--rate-range", type=_rate_range, default="5,80",
                       help="generate: min,max Mbit/s the regime means are drawn from "
                       "(default 5,80)")
    trace.add_argument("--regime", type=float, default=60.0,
                       help="generate: mean s a regime lasts, exponential (default %(default)s)")
    trace.add_argument("--noise", type=float, default=0.15,
                       help="generate: relative std of samples around the regime mean "
                       "(default %(default)s)")
    trace.add_argument("--outage", type=_outage, action="append", metavar="START:SECONDS",
                       help="generate: a 0 Mbit/s outage at START s lasting SECONDS (repeat)")
    trace.add_argument("--outage-every", type=float, default=0.0,
                       help="generate: also random outages, one per this many s on average "
                       "(default 0: none)")
    trace.add_argument("--outage-length", type=float, default=5.0,
                       help="generate: mean s a random outage lasts (default %(default)s)")
    trace.add_argument("--seed", type=int, default=0, help="generate: random seed (default 0)")
    trace.add_argument("--states", type=int, default=4,
                       help="N rate states to report quantile thresholds for (default 4)")
    trace.set_defaults(func=cmd_trace)
    exp = sub.add_parser("experiment", help="reproduce a paper figure (CSV + PNG)",
                         description="udt-fig3/4/5: the digital twin's transition-matrix "
                         "error (paper Figs 3-5); twin-predict: every rate model predicts the "
                         "next slot's state online on chains, generated and real traces "
                         "(log-likelihood, Brier); fig7/8/9: mean υ, lost share and υ tracked "
                         "of the policies vs the high-rate share, N, V_max (paper Figs 7-9).")
    exp.add_argument("name", choices=["udt-fig3", "udt-fig4", "udt-fig5", "twin-predict",
                                      "fig7", "fig8", "fig9"], help="which figure")
    exp.add_argument("--runs", type=int, default=None, help="independent runs per point "
                     "(default: 20; twin-predict: 5 seeds per source; the paper's fig7-9 "
                     "use 15)")
    exp.add_argument("--source", action="append", metavar="SPEC",
                     help="twin-predict: a state sequence to predict (repeat): stationary, "
                     "intervals:K (a new random matrix every K slots), "
                     "generator[:REGIME_S[:OUTAGE_EVERY_S]] (a generated trace with regime "
                     "changes and outages), trace:FILE (default: stationary, intervals:200, "
                     "intervals:600, intervals:1500, generator)")
    exp.add_argument("--trace", action="append", metavar="FILE",
                     help="twin-predict: also a throughput trace file (repeat; same as "
                     "--source trace:FILE; formats as `twinslam trace info`)")
    exp.add_argument("--predictor", default="all",
                     help="twin-predict: all, or comma-separated predictors: regime (the Bayesian "
                     "twin), udt (the variational twin), lstm (softmax), lstm-point (the "
                     "paper's point predictor, 1 - 0.05 on its prediction), markov (counts over "
                     "the whole history), markov-window (counts over the buffer), persistence "
                     "(0.9 on staying), uniform")
    exp.add_argument("--slot-seconds", type=float, default=SLOT_SECONDS,
                     help="twin-predict: seconds of trace per slot")
    exp.add_argument("--policy", action="append", metavar="LABEL[@N]=CHECKPOINT",
                     help="fig7-9: a trained policy to compare (repeat); the same LABEL "
                     "repeated: one variant over several training runs (mean and CI over the "
                     "runs); @N: for N states (fig8)")
    exp.add_argument("--covis", metavar="FILE[@START:END]|geometric[:N[:SEED]]",
                     default=str(REPO_ROOT / "data" / "7scenes-redkitchen-1000.covis.npz"),
                     help="fig7-9: covisibility dataset")
    exp.add_argument("--slots", type=int, default=None,
                     help="slots per run (default: fig7-9 200; twin-predict 3000, a trace at "
                     "most one pass)")
    exp.add_argument("--reference-swaps", type=int, default=100,
                     help="fig7-9: plan replays the reference's swap local search may spend "
                     "per episode (0: beam search only)")
    exp.add_argument("--seed", type=int, default=0, help="the first run's seed")
    exp.add_argument("--states", type=int, default=None,
                     help="N, rate states (default: udt-fig5 2, twin-predict 4)")
    exp.add_argument("--interval-slots", type=int, default=300,
                     help="udt-fig4/5: K, slots per interval of one transition matrix")
    exp.add_argument("--retrain-every", type=int, default=None,
                     help="W, slots between retrains of the learned predictors (default: "
                     "udt-fig4/5 300, twin-predict 100)")
    exp.add_argument("--buffer-slots", type=int, default=None,
                     help="latest slots a retrain learns from; twin-predict: also "
                     "markov-window's window (default: udt-fig4/5 300, twin-predict 600)")
    exp.add_argument("--out", default="results", metavar="FOLDER",
                     help="folder for the CSV and PNG")
    exp.add_argument("--jobs", type=int, default=1,
                     help="runs in parallel worker processes (one torch thread each)")
    exp.set_defaults(func=cmd_experiment)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
