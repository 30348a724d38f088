"""The twin's experiments (paper Figs 3–5): how well each estimator recovers the transition
matrix of the interval it is in.

Protocol, shared by the three figures: a Markov chain runs interval after interval, each with
its own matrix (Dirichlet(1) rows) or the same one (stationary). Every estimator sees every
slot's state as it happens; the twin and the LSTM retrain every W slots on their latest
buffer, warm-started. At each interval's last slot each estimator gives its matrix, scored by
:func:`~twinslam.twin.rate_history.transition_error` (mean absolute difference over the N² entries)
against that interval's true matrix.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twinslam.experiments.parallel import run_all
from twinslam.reporting import mean_ci95, pyplot, write_csv
from twinslam.sweeps import Executor, TaskFailure
from twinslam.twin.lstm import LstmConfig, LstmPredictor
from twinslam.twin.markov import MarkovCounts
from twinslam.twin.rate_history import transition_error
from twinslam.twin.rate_model import MatrixEstimator
from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin
from twinslam.uplink.channels import chain_states, random_transition_matrix

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Protocol:
    interval_slots: int = 300      #: K
    retrain_every: int = 300       #: W; = K here, so every interval ends with a retrain...
    buffer_slots: int = 300        #: ...on that interval's slots
    history: int = 8


def _make(name: str, n: int, proto: Protocol, seed: int) -> MatrixEstimator:
    if name.startswith("udt"):
        z = int(name.split("z")[-1]) if "z" in name else VariationalConfig.latent_dim
        return VariationalTwin(VariationalConfig(
            n_states=n, latent_dim=z, history=proto.history, buffer_slots=proto.buffer_slots,
            retrain_every=proto.retrain_every, seed=seed))
    if name == "lstm":
        return LstmPredictor(LstmConfig(n_states=n, history=proto.history,
                                        buffer_slots=proto.buffer_slots,
                                        retrain_every=proto.retrain_every, seed=seed))
    if name == "markov":
        return MarkovCounts(n)
    if name == "markov_window":
        return MarkovCounts(n, window=proto.buffer_slots)
    raise ValueError(f"unknown estimator {name!r}")


def interval_errors(matrices: list[np.ndarray], estimators: list[str], proto: Protocol,
                    seed: int) -> tuple[dict[str, list[float]], dict[str, np.ndarray]]:
    """Per estimator, its error at the end of every interval; and its last estimate."""
    rng = np.random.default_rng(seed)
    states = chain_states(matrices, proto.interval_slots, rng)
    n = matrices[0].shape[0]
    models = {name: _make(name, n, proto, seed) for name in estimators}
    errors: dict[str, list[float]] = {name: [] for name in estimators}
    last: dict[str, np.ndarray] = {}
    for k, s in enumerate(states):
        for model in models.values():
            if model.observe(int(s)):                     # twin / LSTM: retrain is due
                model.retrain()
        if (k + 1) % proto.interval_slots == 0:
            truth = matrices[k // proto.interval_slots]
            for name, model in models.items():
                last[name] = model.transition_matrix()
                errors[name].append(transition_error(last[name], truth))
    return errors, last


# -- the three figures ---------------------------------------------------------------------------

def fig3(out_dir: Path, seed: int = 0, proto: Protocol | None = None,
         progress: Progress | None = None) -> dict[str, object]:
    """Estimated vs actual matrix of a 4-state chain within one interval (heatmaps)."""
    proto = proto or replace(Protocol(), interval_slots=1000)
    truth = random_transition_matrix(np.random.default_rng(seed), 4)
    errors, last = interval_errors([truth], ["udt"], proto, seed)
    est = last["udt"]
    if progress:
        progress(f"fig3: error {errors['udt'][0]:.4f}")
    write_csv(out_dir / "udt_fig3.csv", ["matrix", "from_state", *[f"to_{j}" for j in range(4)]],
               [["estimated", i, *est[i]] for i in range(4)]
               + [["actual", i, *truth[i]] for i in range(4)])
    _heatmaps(out_dir / "udt_fig3.png", est, truth)
    return {"error": errors["udt"][0], "estimated": est, "actual": truth}


def _fig4_run(task: tuple[int, int, int, tuple[str, ...], Protocol]
              ) -> tuple[int, dict[str, float]]:
    """One Fig 4 run: 3 intervals with their own random N-state matrices."""
    n, r, seed, names, proto = task
    rng = np.random.default_rng([seed, n, r])
    matrices = [random_transition_matrix(rng, n) for _ in range(3)]
    errors, _ = interval_errors(matrices, list(names), proto, seed * 1000 + r)
    return n, {name: float(np.mean(errors[name])) for name in names}


def _fig5_run(task: tuple[str, int, int, int, int, Protocol]
              ) -> tuple[str, dict[str, list[float]]]:
    """One Fig 5 run: ``intervals`` intervals, one matrix or a new one each."""
    mode, r, seed, n_states, intervals, proto = task
    rng = np.random.default_rng([seed, 5, r])
    first = random_transition_matrix(rng, n_states)
    matrices = [first if mode == "stationary" or t == 0 else
                random_transition_matrix(rng, n_states) for t in range(intervals)]
    errors, _ = interval_errors(matrices, ["udt", "markov", "markov_window"], proto,
                                seed * 1000 + r)
    return mode, errors


def fig4(out_dir: Path, runs: int = 20, states: tuple[int, ...] = (2, 3, 4, 5, 6),
         latent_sizes: tuple[int, int] = (2, 8), seed: int = 0,
         proto: Protocol | None = None, progress: Progress | None = None,
         executor: Executor | None = None, failures: list[TaskFailure] | None = None
         ) -> dict[str, dict[int, list[float]]]:
    """Error vs N for the twin with two latent sizes and the LSTM; each run = 3 intervals with
    different matrices, its error the mean over the intervals' ends. The runs go to
    ``executor`` (None: this process); one that fails is added to ``failures`` and left out."""
    proto = proto or Protocol()
    names = (*(f"udt_z{z}" for z in latent_sizes), "lstm")
    tasks = [(n, r, seed, names, proto) for n in states for r in range(runs)]
    done = run_all(_fig4_run, tasks, executor, lambda t: f"fig4 N={t[0]} run {t[1]}",
                   lambda res: f"fig4 N={res[0]}: " + ", ".join(
                       f"{k} {v:.3f}" for k, v in res[1].items()), progress,
                   failures=failures)
    result: dict[str, dict[int, list[float]]] = {name: {n: [] for n in states} for name in names}
    for n, errors in done:
        for name in names:
            result[name][n].append(errors[name])
    rows = [[name, n, float(np.mean(v)), _ci95(v), len(v)]
            for name in names for n, v in result[name].items()]
    write_csv(out_dir / "udt_fig4.csv", ["estimator", "n_states", "mean_error", "ci95", "runs"],
               rows)
    _bars(out_dir / "udt_fig4.png", result, states)
    return result


def fig5(out_dir: Path, runs: int = 20, n_states: int = 2, intervals: int = 15,
         seed: int = 0, proto: Protocol | None = None, progress: Progress | None = None,
         executor: Executor | None = None, failures: list[TaskFailure] | None = None
         ) -> dict[str, dict[str, np.ndarray]]:
    """Twin vs Markov model-driven (whole history; and a sliding window of the twin's buffer)
    across 15 intervals, stationary and non-stationary: error per interval, mean of runs
    (``executor`` and ``failures`` as :func:`fig4`)."""
    proto = proto or Protocol()
    names = ["udt", "markov", "markov_window"]
    modes = ("stationary", "non-stationary")
    tasks = [(mode, r, seed, n_states, intervals, proto) for mode in modes for r in range(runs)]
    done = run_all(_fig5_run, tasks, executor, lambda t: f"fig5 {t[0]} run {t[1]}",
                   lambda res: f"fig5 {res[0]}: " + ", ".join(
                       f"{k} {np.mean(v):.3f}" for k, v in res[1].items()), progress,
                   failures=failures)
    result: dict[str, dict[str, np.ndarray]] = {
        mode: {name: np.array([e[name] for m, e in done if m == mode]) for name in names}
        for mode in modes}
    rows = [[mode, name, t + 1, float(v[:, t].mean()), _ci95(v[:, t]), v.shape[0]]
            for mode, by in result.items() for name, v in by.items()
            for t in range(v.shape[1])]
    write_csv(out_dir / "udt_fig5.csv",
               ["mode", "estimator", "interval", "mean_error", "ci95", "runs"], rows)
    _lines(out_dir / "udt_fig5.png", result)
    return result


# -- output ----------------------------------------------------------------------------------

def _ci95(values: list[float] | np.ndarray) -> float:
    """The 95 % half-width every table uses (:func:`twinslam.reporting.mean_ci95`, Student t;
    the figures committed before 2026-11-28 used the normal 1.96, 7 % narrower at 20 runs)."""
    return mean_ci95([float(x) for x in np.asarray(values, dtype=np.float64).ravel()])[1]


def _heatmaps(path: Path, estimated: np.ndarray, actual: np.ndarray) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), layout="constrained")
    for ax, m, title in zip(axes, (estimated, actual),
                            ("(a) estimated by the UDT", "(b) actual"), strict=True):
        im = ax.imshow(m, vmin=0, vmax=1, cmap="viridis")
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center",
                        color="w" if m[i, j] < 0.6 else "k")
        ax.set_title(title)
        ax.set_xticks(range(m.shape[1]))
        ax.set_yticks(range(m.shape[0]))
        ax.set_xlabel("next state")
        ax.set_ylabel("current state")
    fig.colorbar(im, ax=axes, shrink=0.8, label="transition probability")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _bars(path: Path, result: dict[str, dict[int, list[float]]], states: tuple[int, ...]) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / len(result)
    for i, (name, by_n) in enumerate(result.items()):
        means = [np.mean(by_n[n]) for n in states]
        errs = [_ci95(by_n[n]) for n in states]
        ax.bar(np.arange(len(states)) + i * width, means, width, yerr=errs, capsize=3,
               label=name.replace("udt_z", "UDT, Z = ").replace("lstm", "LSTM"))
    ax.set_xticks(np.arange(len(states)) + width * (len(result) - 1) / 2, [str(n) for n in states])
    ax.set_xlabel("number of states N")
    ax.set_ylabel("error of the estimated transition matrix")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _lines(path: Path, result: dict[str, dict[str, np.ndarray]]) -> None:
    plt = pyplot()
    labels = {"udt": "UDT", "markov": "Markov model-driven",
              "markov_window": "Markov model-driven, sliding window"}
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, (mode, by) in zip(axes, result.items(), strict=True):
        for name, v in by.items():
            x = np.arange(1, v.shape[1] + 1)
            ax.errorbar(x, v.mean(axis=0), yerr=[_ci95(v[:, t]) for t in range(v.shape[1])],
                        marker="o", capsize=3, label=labels[name])
        ax.set_title(f"({'a' if mode == 'stationary' else 'b'}) {mode} uplink data rate")
        ax.set_xlabel("time interval")
    axes[0].set_ylabel("error of the estimated transition matrix")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
