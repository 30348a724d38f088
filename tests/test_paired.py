"""The figures' controls and paired column: a paired difference is taken episode by episode —
Student's t over the episodes for one run, a two-level bootstrap over training runs and
episodes for several — and fig7 reports random and the untrained actor beside the rules,
each paired with the best rule on the same episodes."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from twinslam.experiments import amm
from twinslam.reporting import mean_ci95, paired_difference

COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"


def test_a_constant_gap_is_found_exactly_and_noise_widens_the_interval() -> None:
    base = np.array([-500.0, -400.0, -900.0, -650.0])
    same_gap = paired_difference(np.array([base + 3.0, base + 3.0]), base)
    assert (same_gap.mean, same_gap.low, same_gap.high) == pytest.approx((3.0, 3.0, 3.0))
    assert same_gap.apart
    rng = np.random.default_rng(1)
    noisy = paired_difference(base + rng.normal(0, 20, size=(5, 4)), base)
    assert noisy.low < noisy.mean < noisy.high and not noisy.apart
    # the episodes' spread is paired away: a large spread between episodes, a small gap
    assert paired_difference(np.array([base - 1.0]), base).high == pytest.approx(-1.0)


def test_one_run_gets_student_t_over_its_paired_differences() -> None:
    """Three seeds of a device variant against a baseline: differences 1, 2, 3 give the mean
    2 ± t(0.975, 2 df) · s / √3 = 2 ± 4.303 · 1 / √3 — what every table's mean ± CI gives a
    list of runs (mean_ci95), not a bootstrap's narrower interval over three values."""
    base = np.array([10.0, 20.0, 30.0])
    d = paired_difference(np.array([base + np.array([1.0, 2.0, 3.0])]), base)
    assert (d.mean, d.high - d.mean) == pytest.approx((2.0, 4.302653 / np.sqrt(3)))
    assert (d.mean, d.high - d.mean) == pytest.approx(mean_ci95([1.0, 2.0, 3.0]))
    assert not d.apart
    # a seed a variant could not measure (NaN) is left out, as in mean_ci95
    assert paired_difference(np.array([[1.0, np.nan, 3.0, 2.0]]), np.zeros(4)).mean == 2.0


def test_episodes_that_do_not_pair_are_refused() -> None:
    with pytest.raises(ValueError, match="the same episodes"):
        paired_difference(np.zeros((2, 3)), np.zeros(4))
    with pytest.raises(ValueError, match="the same runs and episodes"):
        paired_difference(np.zeros((2, 3)), np.zeros((3, 3)))


def test_each_run_against_its_own_baseline() -> None:
    """A trained actor against its own run's untrained one: run r's gap is taken from run r's
    baseline, not a shared one (runs far apart, the same small gain in each)."""
    start = np.array([[-900.0, -800.0, -850.0], [-300.0, -200.0, -250.0]])
    gain = paired_difference(start - 5.0, start)
    assert (gain.mean, gain.low, gain.high) == pytest.approx((-5.0, -5.0, -5.0))


def test_fig7_has_random_and_the_untrained_actor_paired_with_the_best_rule(
        tmp_path: Path) -> None:
    setting = amm.Setting(runs=3, slots=6, reference_swaps=0)
    results = amm.fig7(str(COVIS), {}, tmp_path, setting, ratios=(0.5,), controls=2)
    by = results[0.5]
    assert {"LFF", "PU", "ADAPT", "RANDOM", amm.UNTRAINED} <= set(by)
    untrained = by[amm.UNTRAINED]
    assert isinstance(untrained, amm.VariantResult) and len(untrained.checkpoints) == 2
    assert sorted(p.name for p in (tmp_path / "untrained").iterdir()) == [
        "paper_n2_s0.pt", "paper_n2_s1.pt"]
    with (tmp_path / "fig7.csv").open() as fh:
        rows = {r["policy"]: r for r in csv.DictReader(fh)}
    # the best rule is the rule of the lowest mean υ over the episodes (worked out here from
    # the per-episode scores), every row names it, and each rule and RANDOM is paired with it
    # episode by episode: its mean gap, and no other rule's is below zero
    means = {label: float(np.mean(by[label].per_seed)) for label in ("LFF", "PU", "ADAPT")}
    best = min(means, key=lambda label: means[label])
    assert {r["best_rule"] for r in rows.values()} == {best}
    for label in ("LFF", "PU", "ADAPT", "RANDOM"):
        gap = float(np.mean(np.asarray(by[label].per_seed) - np.asarray(by[best].per_seed)))
        assert float(rows[label]["paired_vs_best_rule"]) == pytest.approx(gap, abs=1e-6)
        assert label == "RANDOM" or gap >= 0.0
    low, high = (float(rows[amm.UNTRAINED][k]) for k in ("paired_ci_low", "paired_ci_high"))
    assert low <= float(rows[amm.UNTRAINED]["paired_vs_best_rule"]) <= high
    assert rows[amm.UNTRAINED]["training_runs"] == "2"
    assert rows[amm.BOUND]["paired_vs_best_rule"] == ""
