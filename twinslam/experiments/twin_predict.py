"""``twinslam experiment twin-predict``: every rate model predicts the next slot's state online,
on synthetic chains, on generated traces and on any throughput trace a user has.

A source is one of

* ``stationary`` — one Dirichlet(1) N-state matrix throughout;
* ``intervals:K`` — a new Dirichlet(1) matrix every K slots, the first interval cut at a random
  point so changes do not systematically line up with the learned predictors' retrains;
* ``generator[:REGIME_S[:OUTAGE_EVERY_S]]`` — a trace from
  :func:`twinslam.uplink.traces.generate_trace` (regimes of random mean rate lasting
  REGIME_S s on average, noise, outages), replayed in slots at its real Mbit/s;
* ``trace:FILE`` — a throughput trace file (``twinslam trace info`` reads the same formats).

Traces become states the way the project replays them
(:class:`~twinslam.uplink.channels.TraceChannel`): slot rate = the mean of the sample step
function over the slot, state = its quantile bin of the trace's own per-slot rates. A seed
draws the chain, the generated trace, or — for a trace file — where in it the run starts; it
also seeds the learned predictors.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twinslam.experiments.parallel import run_all
from twinslam.reporting import mean_ci95, pyplot, write_csv
from twinslam.sweeps import Executor, TaskFailure
from twinslam.twin.prediction_score import score_online
from twinslam.twin.registry import PREDICTORS, RateModelSettings, check_names, make_rate_models
from twinslam.uplink.channels import (
    SLOT_SECONDS,
    TraceChannel,
    chain_states,
    random_transition_matrix,
)
from twinslam.uplink.traces import TraceShape, generate_trace

Progress = Callable[[str], None]

DEFAULT_SOURCES = ("stationary", "intervals:200", "intervals:600", "intervals:1500",
                   "generator")
#: the generator's default regimes and outages (seconds): regimes of ~2 min, an outage of
#: ~10 s every ~5 min
GENERATOR_REGIME_S, GENERATOR_OUTAGE_EVERY_S, GENERATOR_OUTAGE_S = 120.0, 300.0, 10.0


#: the counting estimators the others are compared with
COUNTING = ("markov", "markov-window")
#: how every model is built for the experiment: the twin node's defaults, 4 states, KT counts
PREDICTION_SETTINGS = RateModelSettings(n_states=4, pseudo_count=0.5)


@dataclass(frozen=True)
class Setting:
    slots: int = 3000
    seeds: int = 5
    seed0: int = 0
    slot_seconds: float = SLOT_SECONDS
    predictors: tuple[str, ...] = PREDICTORS
    #: the learned models' protocol and the counts' KT smoothing (a maximum-likelihood 0 would
    #: score −∞ nats)
    settings: RateModelSettings = PREDICTION_SETTINGS


def check_source(spec: str, slot_seconds: float = SLOT_SECONDS) -> None:
    """Raise ValueError for a source that cannot be read, before any run starts."""
    kind, _, arg = spec.partition(":")
    if kind == "stationary" and not arg:
        return
    if kind == "intervals":
        if not arg.isdigit() or int(arg) < 1:
            raise ValueError(f"{spec!r}: intervals:K takes K >= 1 slots")
        return
    if kind == "generator":
        _generator_seconds(spec)
        return
    if kind == "trace":
        if not Path(arg).is_file():
            raise ValueError(f"{spec!r}: no such trace file {arg!r}")
        channel = TraceChannel.from_csv(Path(arg), 2)   # raises TraceError on a bad file
        if channel.duration_s < 2 * slot_seconds:
            raise ValueError(f"{spec!r}: the trace lasts {channel.duration_s:g} s, fewer than "
                             f"2 slots of {slot_seconds:g} s to predict")
        return
    raise ValueError(f"unknown source {spec!r}; use stationary, intervals:K, "
                     "generator[:REGIME_S[:OUTAGE_EVERY_S]] or trace:FILE")


def source_states(spec: str, seed: int, setting: Setting) -> np.ndarray:
    """The state sequence of one run of a source (at most ``setting.slots`` states)."""
    n, slots = setting.settings.n_states, setting.slots
    kind, _, arg = spec.partition(":")
    rng = np.random.default_rng([seed, 20])
    if kind == "stationary":
        return chain_states([random_transition_matrix(rng, n)], slots, rng)
    if kind == "intervals":
        k = int(arg)
        phase = int(rng.integers(1, k + 1))           # the first interval: 1..K slots
        matrices = [random_transition_matrix(rng, n) for _ in range(slots // k + 2)]
        states = chain_states(matrices, k, rng)
        return states[k - phase:k - phase + slots]
    if kind == "generator":
        regime_s, every_s = _generator_seconds(spec)
        shape = TraceShape(seconds=slots * setting.slot_seconds, regime_s=regime_s,
                           outage_every_s=every_s, outage_s=GENERATOR_OUTAGE_S)
        times, mbps = generate_trace(shape, seed)
        return _replay(TraceChannel.from_samples(times, mbps, n, slot_seconds=setting.slot_seconds,
                                                 start_s=0.0), slots)
    channel = TraceChannel.from_csv(Path(arg), n, slot_seconds=setting.slot_seconds,
                                    seed=seed)
    one_pass = max(1, int(channel.duration_s // setting.slot_seconds))
    return _replay(channel, min(slots, one_pass))


def _generator_seconds(spec: str) -> tuple[float, float]:
    """(REGIME_S, OUTAGE_EVERY_S) of ``generator[:REGIME_S[:OUTAGE_EVERY_S]]``, defaults filled
    in; ValueError unless each given one is a positive number."""
    _, _, arg = spec.partition(":")
    parts = arg.split(":") if arg else []
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = [-1.0]
    if len(parts) > 2 or any(not v > 0 for v in values):
        raise ValueError(f"{spec!r}: generator[:REGIME_S[:OUTAGE_EVERY_S]] takes positive "
                         "seconds")
    defaults = [GENERATOR_REGIME_S, GENERATOR_OUTAGE_EVERY_S]
    regime_s, every_s = values + defaults[len(values):]
    return regime_s, every_s


def _replay(channel: TraceChannel, slots: int) -> np.ndarray:
    return np.array([channel.step()[0] for _ in range(slots)], dtype=np.int64)


@dataclass(frozen=True)
class RunScore:
    source: str
    seed: int
    predictor: str
    mean_log_likelihood: float
    mean_brier: float
    slots: int


def _run(task: tuple[str, int, Setting]) -> list[RunScore]:
    """One (source, seed): every predictor over the same states."""
    spec, seed, setting = task
    states = source_states(spec, seed, setting)
    models = make_rate_models(setting.predictors, replace(setting.settings, seed=seed))
    scores = score_online(states.tolist(), models)
    return [RunScore(spec, seed, name, s.mean_log_likelihood, s.mean_brier, s.slots)
            for name, s in scores.items()]


@dataclass(frozen=True)
class Summary:
    """One predictor on one source over its seeds."""

    source: str
    predictor: str
    log_likelihood: tuple[float, float]       #: mean, 95 % CI over seeds
    brier: tuple[float, float]
    runs: int
    #: paired per seed: this predictor's log-likelihood minus the best counting estimator's
    #: (the one with the higher mean on this source); > 0 = better than counting
    vs_counting: tuple[float, float]


def summarise(scores: Sequence[RunScore]) -> list[Summary]:
    out: list[Summary] = []
    for source in dict.fromkeys(s.source for s in scores):
        rows = [s for s in scores if s.source == source]
        by = {name: {s.seed: s for s in rows if s.predictor == name}
              for name in dict.fromkeys(s.predictor for s in rows)}
        counting = [c for c in COUNTING if c in by]
        best = max(counting, key=lambda c: np.mean([s.mean_log_likelihood
                                                     for s in by[c].values()]), default=None)
        for name, per_seed in by.items():
            seeds = sorted(per_seed)
            diff = ([per_seed[k].mean_log_likelihood - by[best][k].mean_log_likelihood
                     for k in seeds] if best else [])
            out.append(Summary(
                source, name,
                mean_ci95([per_seed[k].mean_log_likelihood for k in seeds]),
                mean_ci95([per_seed[k].mean_brier for k in seeds]), len(seeds),
                mean_ci95(diff) if diff else (math.nan, math.nan)))
    return out


def twin_predict(sources: Sequence[str], out_dir: Path, setting: Setting,
                 progress: Progress | None = None, executor: Executor | None = None,
                 failures: list[TaskFailure] | None = None) -> list[Summary]:
    """Every predictor on every (source, seed); writes twin_predict.csv (summary),
    twin_predict_runs.csv (every run) and twin_predict.png. The runs go to ``executor``
    (None: this process); a run that fails is added to ``failures`` (its traceback also in
    ``out_dir``/failures.txt) and the summary is over the others."""
    check_names(setting.predictors)
    for spec in sources:
        check_source(spec, setting.slot_seconds)
    tasks = [(spec, setting.seed0 + r, setting) for spec in sources
             for r in range(setting.seeds)]
    done = run_all(_run, tasks, executor, lambda t: f"{t[0]} seed {t[1]}",
                   lambda res: f"{res[0].source} seed {res[0].seed}: "
                   + ", ".join(f"{s.predictor} {s.mean_log_likelihood:.3f}" for s in res),
                   progress, out_dir / "failures.txt", failures)
    if not done:
        return []
    scores = [s for res in done for s in res]
    write_csv(out_dir / "twin_predict_runs.csv",
              ["source", "seed", "predictor", "mean_log_likelihood", "mean_brier", "slots"],
              [[s.source, s.seed, s.predictor, s.mean_log_likelihood, s.mean_brier, s.slots]
               for s in scores])
    summary = summarise(scores)
    write_csv(out_dir / "twin_predict.csv",
              ["source", "predictor", "mean_log_likelihood", "ci95", "mean_brier",
               "brier_ci95", "runs", "minus_best_counting", "minus_best_counting_ci95"],
              [[m.source, m.predictor, *m.log_likelihood, *m.brier, m.runs, *m.vs_counting]
               for m in summary])
    plot(out_dir / "twin_predict.png", summary)
    return summary


def plot(path: Path, summary: Sequence[Summary]) -> None:
    """One panel per source: each predictor's mean log-likelihood per slot with its 95 % CI
    (higher is better); the best counting estimator's level dashed."""
    plt = pyplot()
    sources = list(dict.fromkeys(m.source for m in summary))
    cols = min(3, len(sources))
    rows = math.ceil(len(sources) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.6 * rows), squeeze=False,
                             layout="constrained")
    for ax, source in zip(axes.ravel(), sources, strict=False):
        ms = [m for m in summary if m.source == source]
        y = np.arange(len(ms))
        means = np.array([m.log_likelihood[0] for m in ms])
        cis = np.nan_to_num([m.log_likelihood[1] for m in ms])
        colors = ["tab:red" if m.predictor == "regime" else "tab:blue"
                  if m.predictor in COUNTING else "tab:gray" for m in ms]
        for yi, mean, ci, color in zip(y, means, cis, colors, strict=True):
            ax.errorbar(mean, yi, xerr=ci, fmt="o", color=color, capsize=3)
        ax.set_yticks(y, [m.predictor for m in ms])
        ax.invert_yaxis()
        # a predictor far below the rest (the point LSTM) would squash the others: it sits
        # on the axis' left edge with its value written beside it
        shown = means >= np.median(means) - 1.0
        lo = float(np.min(means[shown] - cis[shown]))
        hi = float(np.max(means[shown] + cis[shown]))
        pad = 0.08 * max(hi - lo, 0.02)
        ax.set_xlim(lo - pad, hi + pad)
        for yi, v in zip(y, means, strict=True):
            off = v < lo - pad
            ax.annotate(f"{'◄ ' if off else ''}{v:.3f}", (max(v, lo - pad), yi),
                        xytext=(2 if off else 4, 0 if off else 4), textcoords="offset points",
                        fontsize=7, va="center" if off else "bottom")
        counting = [m.log_likelihood[0] for m in ms if m.predictor in COUNTING]
        if counting:
            ax.axvline(max(counting), color="tab:blue", ls="--", lw=1)
        ax.set_title(source if len(source) < 40 else "…" + source[-38:])
        ax.set_xlabel("mean log p(next state), nats/slot (higher is better)")
    for ax in axes.ravel()[len(sources):]:
        ax.set_visible(False)
    fig.savefig(path, dpi=120)
    plt.close(fig)
