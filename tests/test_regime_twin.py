"""The Bayesian regime twin: what a policy and the udt node rely on it for."""

from __future__ import annotations

import io

import numpy as np
import pytest

from twinslam.twin.markov import MarkovCounts
from twinslam.twin.prediction_score import score_online
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin
from twinslam.twin.registry import RateModelSettings, load_rate_model, make_rate_model
from twinslam.uplink.channels import chain_states, random_transition_matrix

#: torch (and torch_geometric) load inside the tests, and the tests that load them run on one
#: worker: every xdist worker collects every module, and collecting the suite costs 3 s of CPU
#: without torch, 7 s with it
pytestmark = pytest.mark.xdist_group("torch")

STAY = np.array([[0.95, 0.05], [0.05, 0.95]])
FLIP = np.array([[0.05, 0.95], [0.95, 0.05]])


def test_on_a_stationary_chain_it_predicts_as_well_as_counting_the_whole_history() -> None:
    """Where nothing changes, the mixture must not pay for looking for changes: within 1 % of
    whole-history counting, and the never-changing hazard carries the posterior."""
    rng = np.random.default_rng(3)
    states = chain_states([random_transition_matrix(rng, 4)], 2000, rng).tolist()
    regime, counting = RegimeTwin(RegimeConfig(n_states=4)), MarkovCounts(4, pseudo_count=0.5)
    scores = score_online(states, [regime, counting])
    ll, ref = scores["regime"].mean_log_likelihood, scores["markov"].mean_log_likelihood
    assert ll > ref - 0.01 * abs(ref), (ll, ref)
    weights = regime.hazard_weights()
    assert weights[regime.config.hazards.index(0.0)] == weights.max()


def test_after_the_regime_changes_it_follows_the_new_matrix_and_counting_does_not() -> None:
    states = chain_states([STAY, FLIP], 400, np.random.default_rng(1))
    twin, counting = RegimeTwin(RegimeConfig(n_states=2)), MarkovCounts(2, pseudo_count=0.5)
    for s in states[:430]:                       # 30 slots into the flipping regime
        twin.observe(int(s))
        counting.observe(int(s))
    current = int(states[429])
    assert twin.predict()[1 - current] > 0.8     # flips, as the new regime does
    assert counting.predict([current])[1 - current] < 0.5
    assert twin.expected_run_length() < 60       # it knows the regime is young
    np.testing.assert_allclose(twin.transition_matrix(), FLIP, atol=0.2)


def test_the_latent_is_the_posterior_over_the_regime_matrix() -> None:
    """μ = E[P] (rows sum to 1), Σ its variance, which shrinks as a regime goes on; the
    version counts the slots seen."""
    twin = RegimeTwin(RegimeConfig(n_states=3))
    states = chain_states([random_transition_matrix(np.random.default_rng(0), 3)], 600,
                          np.random.default_rng(2))
    variances = []
    for k, s in enumerate(states):
        twin.observe(int(s))
        if k in (20, 599):
            lat = twin.latent()
            assert lat.mu.shape == lat.sigma.shape == (9,)
            np.testing.assert_allclose(lat.mu.reshape(3, 3).sum(axis=1), 1.0)
            assert abs(lat.next_state_probs.sum() - 1.0) < 1e-9
            variances.append(lat.sigma.mean())
    assert variances[1] < variances[0] / 5
    assert twin.latent().model_version == 600


def test_artificial_next_states_follow_its_predictive() -> None:
    twin = RegimeTwin(RegimeConfig(n_states=3))
    for s in chain_states([random_transition_matrix(np.random.default_rng(4), 3)], 300,
                          np.random.default_rng(5)):
        twin.observe(int(s))
    draws = twin.sample_next([], 4000, np.random.default_rng(6))
    freq = np.bincount(draws, minlength=3) / draws.size
    np.testing.assert_allclose(freq, twin.predict(), atol=0.03)


def test_reset_forgets_and_bad_states_and_configs_are_refused() -> None:
    twin = RegimeTwin(RegimeConfig(n_states=2))
    for s in [0, 1] * 50:
        twin.observe(s)
    twin.reset()
    np.testing.assert_allclose(twin.predict(), [0.5, 0.5])
    assert twin.version == 0
    with pytest.raises(ValueError, match=r"state 2 outside \[0, 2\)"):
        twin.observe(2)
    with pytest.raises(ValueError, match="hazards"):
        RegimeConfig(hazards=(1.5,))
    with pytest.raises(ValueError, match="prior_strength"):
        RegimeConfig(prior_strength=0.0)


def test_the_regime_rate_model_is_the_default_and_survives_a_checkpoint() -> None:
    """Its configuration round-trips through torch's weights-only loader (what a policy
    checkpoint goes through); each run starts afresh."""
    import torch

    from twinslam.training.trainer import TrainConfig

    assert TrainConfig().rate_model == "regime"
    model = make_rate_model("regime", RateModelSettings(n_states=4))
    assert model.online and model.feature_size == 32
    for s in [0, 1, 2, 3] * 30:
        model.observe(s)
    buf = io.BytesIO()
    torch.save(model.state_dict(), buf)
    buf.seek(0)
    again = load_rate_model("regime", torch.load(buf, weights_only=True))
    assert isinstance(again, RegimeTwin) and isinstance(model, RegimeTwin)
    assert again.config == model.config
    feats = model.features([3])
    assert feats.shape == (32,) and np.all(np.isfinite(feats))
    model.reset()
    np.testing.assert_allclose(model.predict([]), 0.25)
