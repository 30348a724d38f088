"""``twinslam experiment``: a paper figure reproduced (CSV + PNG)."""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from twinslam.cli.arguments import (
    BUNDLED_COVIS,
    add_executor_arguments,
    covisibility,
    open_executor,
)
from twinslam.cli.console import (
    Subparsers,
    elapsed_progress,
    error,
    failed_tasks,
    warn_aliases,
)
from twinslam.covisibility.dataset import CovisibilityError
from twinslam.sweeps import TaskFailure
from twinslam.uplink.channels import SLOT_SECONDS, ChannelError


def learned_checkpoints(specs: list[str]) -> dict[str, dict[str, list[Path]]]:
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


def run_amm_figure(args: argparse.Namespace) -> int:
    """fig7/8/9: the policies' mean υ, lost share and υ tracked vs a setting (paper Figs 7-9)."""
    # imported here: the figures load the trainer (torch), which the other commands never need
    from twinslam.experiments import amm

    t0 = time.monotonic()
    progress = elapsed_progress()
    try:
        learned = learned_checkpoints(args.policy or [])
        covisibility(args.covis)                  # a bad file fails before any worker starts
        executor = open_executor(args)
    except (CovisibilityError, ValueError, RuntimeError) as exc:
        return error(exc)
    setting = amm.Setting(runs=args.runs or 20, slots=args.slots or 200, seed0=args.seed,
                         reference_swaps=args.reference_swaps)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failures: list[TaskFailure] = []
    with executor:
        if args.name == "fig8":
            by_n = {int(n or 2): pol for n, pol in learned.items()}
            results = amm.fig8(args.covis, by_n, out, setting, progress, executor, failures,
                               controls=args.controls)
        else:
            fig = amm.fig7 if args.name == "fig7" else amm.fig9
            results = fig(args.covis, learned.get("", {}), out, setting, progress=progress,
                          executor=executor, failures=failures, controls=args.controls)
    for x, by in results.items():
        paired = amm.paired_rows(by)
        print(f"{x} (mean υ ± 95 % CI; paired with the best rule {amm.best_rule(by)}, "
              "mean [95 % CI over training runs and episodes]):")
        for label, r in by.items():
            diff = paired[label]
            print(f"  {label:<34} {r.mean:9.1f} ± {r.ci95:6.1f}"
                  + (f"   {diff.mean:+8.1f} [{diff.low:+.1f}, {diff.high:+.1f}]"
                     if diff else ""))
    print(f"wrote {out}/{args.name}.csv and .png ({time.monotonic() - t0:.0f} s)")
    return _failed(failures, out)


def _failed(failures: list[TaskFailure], out: Path) -> int:
    """0, or 1 after naming the tasks that failed (their tracebacks are in ``out``)."""
    return failed_tasks(failures, "task(s)", f"{out}/*failures.txt; the tables hold the others")


def run_twin_predict(args: argparse.Namespace) -> int:
    """twin-predict: every rate model predicts the next slot's state online."""
    # imported here: the learned predictors load torch, which the other commands never need
    from twinslam.experiments import twin_predict as ex
    from twinslam.twin.registry import ALIASES, PREDICTORS, check_names

    t0 = time.monotonic()
    progress = elapsed_progress()

    sources = list(args.source or ex.DEFAULT_SOURCES)
    sources += [f"trace:{path}" for path in args.trace or []]
    try:
        settings = replace(ex.PREDICTION_SETTINGS, n_states=args.states or 4,
                           retrain_every=args.retrain_every or 100,
                           buffer_slots=args.buffer_slots or 600)
        predictors = (PREDICTORS if args.predictor == "all" else
                      tuple(p.strip() for p in args.predictor.split(",") if p.strip()))
        check_names(predictors)
        warn_aliases(predictors, ALIASES)
        setting = ex.Setting(slots=args.slots or 3000, seeds=args.runs or 5, seed0=args.seed,
                             slot_seconds=args.slot_seconds, predictors=predictors,
                             settings=settings)
        for spec in sources:
            ex.check_source(spec, args.slot_seconds)
        executor = open_executor(args)
    except (ValueError, ChannelError, RuntimeError) as exc:
        return error(exc)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failures: list[TaskFailure] = []
    with executor:
        summary = ex.twin_predict(sources, out, setting, progress, executor, failures)
    for source in dict.fromkeys(m.source for m in summary):
        print(f"{source}  (mean log p(next state) ± 95 % CI, nats; Brier; "
              f"minus the best counting estimator)")
        for m in summary:
            if m.source == source:
                print(f"  {m.predictor:>14} {m.log_likelihood[0]:8.4f} ± "
                      f"{m.log_likelihood[1]:.4f}  Brier {m.brier[0]:.4f}  "
                      f"{m.vs_counting[0]:+8.4f} ± {m.vs_counting[1]:.4f}")
    if summary:
        print(f"wrote {out}/twin_predict.csv, twin_predict_runs.csv and twin_predict.png "
              f"({time.monotonic() - t0:.0f} s)")
    return _failed(failures, out)


def run_learning_curve(args: argparse.Namespace) -> int:
    """learning-curve: every snapshot of every training run on held-out episodes."""
    # imported here: the learned policy loads torch, which the other commands never need
    from twinslam.experiments import learning_curve as ex

    t0 = time.monotonic()
    progress = elapsed_progress()
    files = [Path(f) for f in args.snapshots or []]
    episodes, slots = args.runs or 10, args.slots or 100
    try:
        covisibility(args.covis)
        ex.setup_of(files, args.covis, episodes, slots, args.seed)   # fails before any worker
        executor = open_executor(args)
    except (CovisibilityError, ValueError, RuntimeError) as exc:
        return error(exc)
    out = Path(args.out)
    failures: list[TaskFailure] = []
    with executor:
        result = ex.learning_curve(files, args.covis, out, episodes, slots, args.seed,
                                   progress, executor, failures, every=args.snapshot_every)
    if not result.points:
        return _failed(failures, out)
    print("held-out controls (mean υ ± 95 % CI, lost share; paired with the best rule: mean "
          "[95 % CI]):")
    for row in result.controls:
        label, _, _, mean, ci, lost, _, best, diff, low, high = row
        print(f"  {label:<32} {mean:9.1f} ± {ci:6.1f}  lost {lost:6.1%}"
              + (f"   vs {best} {diff:+8.1f} [{low:+.1f}, {high:+.1f}]" if diff != "" else ""))
    paired = result.paired
    print(f"paired by episode ({episodes} held-out episodes of {slots} slots; mean "
          "[95 % CI over training runs and episodes]):")
    for label, (n_runs, d) in paired.items():
        print(f"  {label:<42} {d.mean:+8.1f} [{d.low:+.1f}, {d.high:+.1f}]  ({n_runs} runs"
              f"{', apart' if d.apart else ''})")
    print(f"wrote {out}/learning_curve.csv, learning_curve_runs.csv, learning_curve_paired.csv, "
          f"learning_curve_controls.csv and learning_curve.png ({time.monotonic() - t0:.0f} s)")
    return _failed(failures, out)


def run(args: argparse.Namespace) -> int:
    if args.name in ("fig7", "fig8", "fig9"):
        return run_amm_figure(args)
    if args.name == "learning-curve":
        return run_learning_curve(args)
    if args.name == "twin-predict":
        return run_twin_predict(args)
    return run_twin_figure(args)


def run_twin_figure(args: argparse.Namespace) -> int:
    """udt-fig3/4/5: the variational twin's transition-matrix error (paper Figs 3-5)."""
    # imported here: the twin loads torch, which the other commands never need
    from twinslam.experiments import twin as ex

    out = Path(args.out)
    args.states = args.states or 2
    args.runs = args.runs or 20
    args.retrain_every = args.retrain_every or 300
    args.buffer_slots = args.buffer_slots or 300
    proto = ex.Protocol(interval_slots=args.interval_slots, retrain_every=args.retrain_every,
                        buffer_slots=args.buffer_slots)
    progress = elapsed_progress()
    try:              # udt-fig3 is one run: it needs no executor
        executor = open_executor(args) if args.name != "udt-fig3" else None
    except (ValueError, RuntimeError) as exc:
        return error(exc)
    failures: list[TaskFailure] = []
    if executor is None:
        res = ex.fig3(out, seed=args.seed, progress=progress,
                      proto=ex.Protocol(interval_slots=max(args.interval_slots, 1000),
                                        retrain_every=args.retrain_every,
                                        buffer_slots=max(args.buffer_slots, 1000)))
        print(f"UDT error on a 4-state chain (mean |P̂ - P|): {res['error']:.4f}")
    elif args.name == "udt-fig4":
        with executor:
            res4 = ex.fig4(out, runs=args.runs, seed=args.seed, proto=proto,
                           progress=progress, executor=executor, failures=failures)
        print(f"{'N':>3} " + " ".join(f"{name:>16}" for name in res4))
        for n in next(iter(res4.values())):
            print(f"{n:>3} " + " ".join(f"{sum(v[n]) / max(1, len(v[n])):16.4f}"
                                        for v in res4.values()))
    else:
        with executor:
            res5 = ex.fig5(out, runs=args.runs, n_states=args.states, seed=args.seed,
                           proto=proto, progress=progress, executor=executor,
                           failures=failures)
        for mode, by in res5.items():
            print(mode + ": " + ", ".join(f"{name} {v.mean():.4f}" for name, v in by.items()))
    print(f"wrote {out}/{args.name.replace('-', '_')}.csv and .png")
    return _failed(failures, out)


def register(sub: Subparsers) -> None:
    exp = sub.add_parser("experiment", help="reproduce a paper figure (CSV + PNG)",
                         description="udt-fig3/4/5: the digital twin's transition-matrix "
                         "error (paper Figs 3-5); twin-predict: every rate model predicts the "
                         "next slot's state online on chains, generated and real traces "
                         "(log-likelihood, Brier); fig7/8/9: mean υ, lost share and υ tracked "
                         "of the policies vs the high-rate share, N, V_max (paper Figs 7-9); "
                         "learning-curve: every validated actor of `twinslam train --snapshots` "
                         "runs scored on held-out episodes beside the rules.")
    exp.add_argument("name", choices=["udt-fig3", "udt-fig4", "udt-fig5", "twin-predict",
                                      "fig7", "fig8", "fig9", "learning-curve"],
                     help="which figure")
    exp.add_argument("--runs", type=int, default=None, help="independent runs per point "
                     "(default: 20; twin-predict: 5 seeds per source; learning-curve: 10 "
                     "held-out episodes; the paper's fig7-9 use 15)")
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
                     "twin), variational (the paper's variational twin; udt: its old name), "
                     "lstm (softmax), lstm-point (the "
                     "paper's point predictor, 1 - 0.05 on its prediction), markov (counts over "
                     "the whole history), markov-window (counts over the buffer), persistence "
                     "(0.9 on staying), uniform")
    exp.add_argument("--slot-seconds", type=float, default=SLOT_SECONDS,
                     help="twin-predict: seconds of trace per slot")
    exp.add_argument("--policy", action="append", metavar="LABEL[@N]=CHECKPOINT",
                     help="fig7-9: a trained policy to compare (repeat); the same LABEL "
                     "repeated: one variant over several training runs (mean and CI over the "
                     "runs); @N: for N states (fig8)")
    exp.add_argument("--snapshots", action="append", metavar="FILE",
                     help="learning-curve: a training run's FILE.snapshots.pt from `twinslam "
                     "train --snapshots` (repeat: one line per run; all of one setting)")
    exp.add_argument("--snapshot-every", type=int, default=0, metavar="SLOTS",
                     help="learning-curve: score one snapshot every SLOTS training slots (and "
                     "always the first, the last and the kept one); default 0: every one")
    exp.add_argument("--covis", metavar="FILE[@START:END]|geometric[:N[:SEED]]",
                     default=str(BUNDLED_COVIS),
                     help="fig7-9, learning-curve: covisibility dataset (learning-curve: "
                     "frames the training never saw, e.g. FILE@600:1000 after training on "
                     "FILE@0:600)")
    exp.add_argument("--slots", type=int, default=None,
                     help="slots per run (default: fig7-9 200; learning-curve 100; "
                     "twin-predict 3000, a trace at most one pass)")
    exp.add_argument("--controls", type=int, default=5, metavar="N",
                     help="fig7-9: beside the rules and random, the paper's actor untrained, "
                     "N initialisations (those training runs 0..N-1 start from), as one "
                     "variant: whether training beats its own starting point; 0: none; "
                     "default %(default)s")
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
    add_executor_arguments(exp, "run")
    exp.set_defaults(func=run)
