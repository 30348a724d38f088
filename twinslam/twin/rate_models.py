"""What the policy knows about the uplink beyond its history: a rate model per variant.

The paper compares the policy driven by the user digital twin with the same policy driven by
an LSTM point predictor and by a Markov-chain count estimator (§VII, Figs 7–9). Each model here
answers the same two questions, so the trainer and the policy do not care which one they hold:

* ``features(history)`` — the state augmentation: the twin's μ and log Σ (VariBAD gives the
  policy the posterior's parameters, not a sample), the LSTM's one-hot prediction, the Markov
  estimate's row for the current state;
* ``sample_next(history, count, rng)`` — next states d̂_{k+1} for artificial experiences.

Each learns online from the states it ``observe``s: the learned ones (twin, LSTM) retrain every
W slots (Algorithm 2 lines 11–13) and keep their weights from run to run; the ``online`` ones
(the Bayesian regime twin, Markov counting) are filters over the current run's states, so a
new run ``reset``s them and a policy feeds them every slot it sees.

The default is ``regime``: it predicts the next state best of all (``twinslam experiment
twin-predict``, docs/results.md).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch

from twinslam.twin.baselines import LstmConfig, LstmPredictor, MarkovMle
from twinslam.twin.digital_twin import TwinConfig, UserDigitalTwin
from twinslam.twin.latent import latent_features
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin


class RateModel(Protocol):
    name: str
    n_states: int
    #: a filter over the current run's states (reset per run, fed every slot), not weights
    online: bool

    def reset(self) -> None: ...

    @property
    def feature_size(self) -> int: ...

    def observe(self, state: int) -> None: ...

    def features(self, history: list[int]) -> np.ndarray: ...

    def sample_next(self, history: list[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray: ...

    def state_dict(self) -> dict: ...


class TwinRateModel:
    """The user digital twin (paper §V): features = [μ, log Σ] of q(z | d_k)."""

    name = "udt"
    online = False

    def __init__(self, n_states: int, retrain_every: int = 100, seed: int = 0,
                 twin: UserDigitalTwin | None = None) -> None:
        self.twin = twin or UserDigitalTwin(TwinConfig(n_states=n_states,
                                                       retrain_every=retrain_every, seed=seed))
        self.n_states = self.twin.config.n_states

    def reset(self) -> None:
        """Nothing: the learned weights carry over from run to run."""

    @property
    def feature_size(self) -> int:
        return 2 * self.twin.config.latent_dim

    def observe(self, state: int) -> None:
        if self.twin.observe(state):
            self.twin.retrain()

    def features(self, history: list[int]) -> np.ndarray:
        lat = self.twin.latent(history)
        return latent_features(lat.mu, lat.sigma)

    def sample_next(self, history: list[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return self.twin.sample_next(count, history, rng)

    def state_dict(self) -> dict:
        return {"config": self.twin.config.__dict__,
                "network": self.twin.network.state_dict(), "version": self.twin.version}

    @classmethod
    def from_state_dict(cls, blob: dict) -> TwinRateModel:
        twin = UserDigitalTwin(TwinConfig(**blob["config"]))
        twin.network.load_state_dict(blob["network"])
        twin.version = int(blob["version"])
        return cls(twin.config.n_states, twin=twin)


class LstmRateModel:
    """The paper's "Proposed (LSTM)": a point predictor; features = its one-hot prediction,
    artificial next states = that prediction (it has no distribution to sample)."""

    name = "lstm"
    online = False

    def __init__(self, n_states: int, retrain_every: int = 100, seed: int = 0,
                 predictor: LstmPredictor | None = None) -> None:
        self.predictor = predictor or LstmPredictor(LstmConfig(
            n_states=n_states, retrain_every=retrain_every, seed=seed))
        self.n_states = self.predictor.config.n_states

    def reset(self) -> None:
        """Nothing: the learned weights carry over from run to run."""

    @property
    def feature_size(self) -> int:
        return self.n_states

    def observe(self, state: int) -> None:
        if self.predictor.observe(state):
            self.predictor.retrain()

    def features(self, history: list[int]) -> np.ndarray:
        out = np.zeros(self.n_states, dtype=np.float32)
        out[self.predictor.predict(history)] = 1.0
        return out

    def sample_next(self, history: list[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return np.full(count, self.predictor.predict(history), dtype=np.int64)

    def state_dict(self) -> dict:
        return {"config": self.predictor.config.__dict__,
                "network": self.predictor.network.state_dict()}

    @classmethod
    def from_state_dict(cls, blob: dict) -> LstmRateModel:
        predictor = LstmPredictor(LstmConfig(**blob["config"]))
        predictor.network.load_state_dict(blob["network"])
        return cls(predictor.config.n_states, predictor=predictor)


class MarkovRateModel:
    """The paper's "Proposed (Markov model)": the maximum-likelihood transition counts over the
    whole history (``twinslam.twin.baselines.MarkovMle``); features = the estimated row of the
    current state, artificial next states drawn from it."""

    name = "markov"
    online = True

    def __init__(self, n_states: int, counts: np.ndarray | None = None) -> None:
        self.n_states = n_states
        self.mle = MarkovMle(n_states)
        if counts is not None:
            self.mle.counts = np.asarray(counts, dtype=np.float64).copy()

    def reset(self) -> None:
        """A new run: the counts start afresh."""
        self.mle = MarkovMle(self.n_states)

    @property
    def feature_size(self) -> int:
        return self.n_states

    def observe(self, state: int) -> None:
        self.mle.observe(state)

    def _row(self, history: list[int]) -> np.ndarray:
        return self.mle.transition_matrix()[history[-1] if history else 0]

    def features(self, history: list[int]) -> np.ndarray:
        return self._row(history).astype(np.float32)

    def sample_next(self, history: list[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return rng.choice(self.n_states, size=count, p=self._row(history))

    def state_dict(self) -> dict:
        return {"n_states": self.n_states, "counts": torch.from_numpy(self.mle.counts.copy())}

    @classmethod
    def from_state_dict(cls, blob: dict) -> MarkovRateModel:
        return cls(int(blob["n_states"]), np.asarray(blob["counts"], dtype=np.float64))


class RegimeRateModel:
    """The Bayesian regime twin (:mod:`twinslam.twin.regime_twin`): features = [μ, log Σ] of
    its posterior over the current regime's matrix (2·N² numbers), artificial next states
    drawn from its posterior predictive."""

    name = "regime"
    online = True

    def __init__(self, n_states: int, config: RegimeConfig | None = None) -> None:
        self.twin = RegimeTwin(config or RegimeConfig(n_states=n_states))
        self.n_states = self.twin.config.n_states

    @property
    def feature_size(self) -> int:
        return 2 * self.n_states * self.n_states

    def reset(self) -> None:
        """A new run: the posterior starts from the prior."""
        self.twin.reset()

    def observe(self, state: int) -> None:
        self.twin.observe(state)

    def features(self, history: list[int]) -> np.ndarray:
        lat = self.twin.latent()
        return latent_features(lat.mu, lat.sigma)

    def sample_next(self, history: list[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        return self.twin.sample_next(count, rng, history[-1] if history else None)

    def state_dict(self) -> dict:
        cfg = self.twin.config
        return {"n_states": cfg.n_states, "hazards": [float(h) for h in cfg.hazards],
                "prior_strength": cfg.prior_strength, "max_hypotheses": cfg.max_hypotheses}

    @classmethod
    def from_state_dict(cls, blob: dict) -> RegimeRateModel:
        return cls(int(blob["n_states"]), RegimeConfig(
            n_states=int(blob["n_states"]),
            hazards=tuple(float(h) for h in blob["hazards"]),
            prior_strength=(None if blob["prior_strength"] is None
                            else float(blob["prior_strength"])),
            max_hypotheses=int(blob["max_hypotheses"])))


RATE_MODELS = {"regime": RegimeRateModel, "udt": TwinRateModel, "lstm": LstmRateModel,
               "markov": MarkovRateModel}
DEFAULT_RATE_MODEL = "regime"
#: the rate models the udt node can run (a policy on one of them can take the node's latent)
TWIN_RATE_MODELS = ("regime", "udt")


def make_rate_model(name: str, n_states: int, retrain_every: int = 100, seed: int = 0
                    ) -> RateModel:
    if name == "markov":
        return MarkovRateModel(n_states)
    if name == "regime":
        return RegimeRateModel(n_states)
    try:
        return RATE_MODELS[name](n_states, retrain_every, seed)
    except KeyError:
        raise ValueError(f"unknown rate model {name!r}; choose from {sorted(RATE_MODELS)}"
                         ) from None


def load_rate_model(name: str, blob: dict) -> RateModel:
    return RATE_MODELS[name].from_state_dict(blob)
