"""Online next-state prediction: the scores, the sources, the experiment's CLI."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from twinslam.experiments import twin_predict as tp
from twinslam.twin.markov import MarkovCounts
from twinslam.twin.naive import Uniform
from twinslam.twin.prediction_score import score_online
from twinslam.twin.registry import RateModelSettings, make_rate_models
from twinslam.uplink.traces import TraceShape, generate_trace, write_trace

CHEAP = ("regime", "markov", "markov-window", "persistence", "uniform")


def test_scores_are_the_log_likelihood_and_brier_of_what_came() -> None:
    """Uniform over 4 states scores log(1/4) and Brier 0.75 on every slot; counting's
    smoothed predictions are the closed form (n_ij + 1/2) / (n_i + 2) on a 2-state sequence."""
    states = [0, 1, 0, 1, 1, 0]
    s = score_online(states, [Uniform(4)])["uniform"]
    assert s.slots == 5
    assert math.isclose(s.mean_log_likelihood, math.log(0.25))
    assert math.isclose(s.mean_brier, 0.75)
    counting = score_online(states, [MarkovCounts(2, pseudo_count=0.5)])["markov"]
    # p(0→1)=1/2, p(1→0)=1/2, p(0→1 | 1 of 1)=3/4, p(1→1 | n10=1)=1/4, p(1→0 | n10=1, n11=1)=1/2
    expected = np.log([0.5, 0.5, 0.75, 0.25, 0.5]).mean()
    assert math.isclose(counting.mean_log_likelihood, expected)


def test_a_predictor_that_is_not_a_distribution_is_refused() -> None:
    class Broken(Uniform):
        name = "broken"

        def predict(self, history: Sequence[int]) -> np.ndarray:
            return np.array([0.7, 0.7])

    with pytest.raises(ValueError, match=r"broken: prediction .* is not a distribution"):
        score_online([0, 1, 0], [Broken(2)])


def test_the_lstm_learns_in_one_retrain_and_the_point_predictor_keeps_epsilon() -> None:
    settings = RateModelSettings(n_states=3, retrain_every=20, buffer_slots=40,
                                 steps_per_retrain=20)
    soft, point = make_rate_models(["lstm", "lstm-point"], settings)
    history = [0, 1, 2] * 10
    score_online(history, [soft, point])
    assert soft.predict(history)[0] > 0.5       # after 2 comes 0: learnt in one retrain
    p = point.predict(history)
    assert sorted(p.tolist()) == pytest.approx([0.025, 0.025, 0.95])
    assert abs(soft.predict(history).sum() - 1.0) < 1e-6
    with pytest.raises(ValueError, match="unknown rate model"):
        make_rate_models(["twin"], settings)


@pytest.mark.parametrize("spec", ["stationary", "intervals:50", "generator:20:60"])
def test_sources_give_states_in_range_and_seeds_differ(spec: str) -> None:
    setting = tp.Setting(slots=300, settings=RateModelSettings(n_states=4))
    a, b = (tp.source_states(spec, seed, setting) for seed in (0, 1))
    assert a.shape == b.shape == (300,)
    assert a.min() >= 0 and a.max() <= 3 and not np.array_equal(a, b)


def test_interval_changes_do_not_line_up_with_retrains() -> None:
    """The first interval is cut at a seed's random point: changes fall off the W grid."""
    setting = tp.Setting(slots=200, settings=RateModelSettings(n_states=2))
    firsts = set()
    for seed in range(6):
        rng = np.random.default_rng([seed, 20])
        firsts.add(int(rng.integers(1, 101)))
        assert tp.source_states("intervals:100", seed, setting).shape == (200,)
    assert len(firsts) > 1


@pytest.mark.parametrize(("bad", "says"), [
    ("interval:5", "unknown source 'interval:5'"),
    ("intervals:0", "intervals:K takes K >= 1"),
    ("generator:-1", "takes positive seconds"),
    ("trace:/no/file", "no such trace file '/no/file'"),
    ("stationary:3", "unknown source 'stationary:3'")])
def test_bad_sources_are_refused_by_name(bad: str, says: str) -> None:
    with pytest.raises(ValueError) as err:
        tp.check_source(bad)
    assert says in str(err.value)


def test_a_trace_shorter_than_two_slots_is_refused(tmp_path: Path) -> None:
    trace = tmp_path / "short.csv"
    write_trace(trace, np.array([0.0, 1.0, 2.0]), np.array([10.0, 20.0, 30.0]))
    with pytest.raises(ValueError, match=r"lasts 3 s, fewer than 2 slots of 2 s"):
        tp.check_source(f"trace:{trace}")


def test_the_regime_twin_beats_counting_where_the_chain_changes(tmp_path: Path) -> None:
    """What the twin is for: on a chain whose matrix changes every 100 slots it predicts
    better than both counting estimators on every seed; the experiment writes every
    predictor's mean, CI and paired difference, every run, and a plot."""
    setting = tp.Setting(slots=600, seeds=3, predictors=CHEAP,
                         settings=RateModelSettings(n_states=3))
    summary = tp.twin_predict(["intervals:100"], tmp_path, setting)
    rows = list(csv.DictReader((tmp_path / "twin_predict_runs.csv").open()))
    by_seed: dict[str, dict[str, float]] = {}
    for r in rows:
        by_seed.setdefault(r["seed"], {})[r["predictor"]] = float(r["mean_log_likelihood"])
    assert len(by_seed) == 3
    for seed, scores in by_seed.items():
        assert scores["regime"] > max(scores["markov"], scores["markov-window"]), seed
    regime = next(m for m in summary if m.predictor == "regime")
    assert regime.runs == 3 and regime.vs_counting[0] > 0
    table = list(csv.DictReader((tmp_path / "twin_predict.csv").open()))
    assert {r["predictor"] for r in table} == set(CHEAP)
    assert all(float(r["ci95"]) >= 0 for r in table)
    assert (tmp_path / "twin_predict.png").stat().st_size > 10_000


@pytest.mark.slow
def test_the_cli_runs_on_a_trace_file_and_refuses_a_bad_source(tmp_path: Path) -> None:
    trace = tmp_path / "uplink.csv"
    write_trace(trace, *generate_trace(TraceShape(seconds=900, regime_s=40,
                                                  outage_every_s=200), seed=3))
    cmd = [sys.executable, "-m", "twinslam.cli.main", "experiment", "twin-predict",
           "--source", "stationary", "--trace", str(trace), "--slots", "300", "--runs", "3",
           "--predictor", "regime,markov,uniform", "--out", str(tmp_path / "out")]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"trace:{trace}" in done.stdout and "regime" in done.stdout
    table = list(csv.DictReader((tmp_path / "out" / "twin_predict.csv").open()))
    assert {(r["source"], r["runs"]) for r in table} == {("stationary", "3"),
                                                         (f"trace:{trace}", "3")}
    bad = subprocess.run([*cmd[:5], "--source", "intervals:x", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "intervals:K takes K >= 1" in bad.stderr
    assert not (tmp_path / "x").exists()
