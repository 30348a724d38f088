"""Online next-state prediction: the one test every rate model can take on real data.

A transition-matrix error (Figs 3–5) needs the true matrix, which only a synthetic chain has.
What a rate model is for — telling the policy what the uplink does next — can be scored on any
state sequence: before slot k + 1 each predictor gives p(d_{k+1}); the state that comes is
scored by its log-likelihood log p(d_{k+1}) (a proper score: only the true distribution
maximises its expectation) and by the Brier score Σ_j (p_j − [j = d_{k+1}])²; then every
predictor observes it (and a learned one retrains when its W slots are up).

Each predictor here wraps one rate model behind ``predict()`` / ``observe(state)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from twinslam.twin.baselines import LstmConfig, LstmPredictor, MarkovMle
from twinslam.twin.digital_twin import TwinConfig, UserDigitalTwin
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin

#: a probability below this is scored as this (a point predictor's 0 would be −∞)
PROBABILITY_FLOOR = 1e-12


class NextStatePredictor(Protocol):
    name: str

    def predict(self) -> np.ndarray: ...

    def observe(self, state: int) -> None: ...


@dataclass(frozen=True)
class PredictionProtocol:
    """What the learned predictors are given: the udt node's defaults."""

    n_states: int = 4
    retrain_every: int = 100      #: W
    buffer_slots: int = 600       #: the twin's buffer; also the counting window
    history: int = 8              #: τ + 1, the networks' input window
    steps_per_retrain: int = 100  #: Adam steps per retrain of the networks
    stay: float = 0.9             #: persistence's probability of staying put
    pseudo_count: float = 0.5     #: counting's Dirichlet smoothing (KT)
    point_epsilon: float = 0.05   #: what a point prediction leaves for the other states


def peaked(n_states: int, state: int, mass: float) -> np.ndarray:
    """``mass`` on ``state``, the rest spread evenly: how a point guess becomes a distribution
    that gives the other states a probability above 0."""
    if n_states == 1:
        return np.ones(1)
    out = np.full(n_states, (1.0 - mass) / (n_states - 1))
    out[state] = mass
    return out


class CountingPredictor:
    """Markov maximum likelihood, smoothed: p(j | i) = (n_ij + α) / (n_i + Nα), over the
    whole history or the last ``window`` transitions."""

    def __init__(self, name: str, n_states: int, window: int | None, pseudo_count: float
                 ) -> None:
        self.name, self.pseudo = name, pseudo_count
        self.mle = MarkovMle(n_states, window)
        self.state = 0

    def predict(self) -> np.ndarray:
        row = self.mle.counts[self.state] + self.pseudo
        return row / row.sum()

    def observe(self, state: int) -> None:
        self.mle.observe(state)
        self.state = int(state)


class PersistencePredictor:
    """"The next slot is like this one": ``stay`` on the current state, the rest spread."""

    def __init__(self, n_states: int, stay: float) -> None:
        self.name, self.n, self.stay, self.state = "persistence", n_states, stay, 0

    def predict(self) -> np.ndarray:
        return peaked(self.n, self.state, self.stay)

    def observe(self, state: int) -> None:
        self.state = int(state)


class UniformPredictor:
    """1/N each: the score of knowing nothing (log N nats)."""

    def __init__(self, n_states: int) -> None:
        self.name, self.n = "uniform", n_states

    def predict(self) -> np.ndarray:
        return np.full(self.n, 1.0 / self.n)

    def observe(self, state: int) -> None:
        pass


class RegimePredictor:
    """The Bayesian regime twin (:mod:`twinslam.twin.regime_twin`)."""

    def __init__(self, n_states: int) -> None:
        self.name, self.twin = "regime", RegimeTwin(RegimeConfig(n_states=n_states))

    def predict(self) -> np.ndarray:
        return self.twin.predict()

    def observe(self, state: int) -> None:
        self.twin.observe(state)


class VaeTwinPredictor:
    """The variational twin (paper §V): p(d_{k+1}) from its decoder with z = μ; retrained
    every W slots on its buffer, warm-started."""

    def __init__(self, proto: PredictionProtocol, seed: int) -> None:
        self.name = "udt"
        self.twin = UserDigitalTwin(TwinConfig(
            n_states=proto.n_states, history=proto.history, buffer_slots=proto.buffer_slots,
            retrain_every=proto.retrain_every, steps_per_retrain=proto.steps_per_retrain,
            seed=seed))

    def predict(self) -> np.ndarray:
        return self.twin.latent().next_state_probs.astype(np.float64)

    def observe(self, state: int) -> None:
        if self.twin.observe(state):
            self.twin.retrain()


class LstmPredictors:
    """One LSTM, two ways to use it: ``lstm`` its softmax, ``lstm-point`` the paper's point
    prediction (1 − ε on the predicted state). Both share the network and its retrains."""

    def __init__(self, proto: PredictionProtocol, seed: int) -> None:
        self.lstm = LstmPredictor(LstmConfig(
            n_states=proto.n_states, history=proto.history, buffer_slots=proto.buffer_slots,
            retrain_every=proto.retrain_every, steps_per_retrain=proto.steps_per_retrain,
            seed=seed))
        self.epsilon = proto.point_epsilon

    def softmax(self) -> np.ndarray:
        return self.lstm.probabilities(self.lstm.states)

    def point(self) -> np.ndarray:
        return peaked(self.lstm.config.n_states, self.lstm.predict(self.lstm.states),
                      1.0 - self.epsilon)

    def observe(self, state: int) -> None:
        if self.lstm.observe(state):
            self.lstm.retrain()


class _View:
    """A named predictor over a shared model (observing through the first view only)."""

    def __init__(self, name: str, predict: Callable[[], np.ndarray],
                 observe: Callable[[int], None] | None) -> None:
        self.name, self._predict, self._observe = name, predict, observe

    def predict(self) -> np.ndarray:
        return self._predict()

    def observe(self, state: int) -> None:
        if self._observe is not None:
            self._observe(state)


PREDICTORS = ("regime", "udt", "lstm", "lstm-point", "markov", "markov-window", "persistence",
              "uniform")
COUNTING = ("markov", "markov-window")


def check_predictors(names: Sequence[str]) -> None:
    """ValueError naming what is not a predictor (without building any network)."""
    unknown = sorted(set(names) - set(PREDICTORS))
    if unknown:
        raise ValueError(f"unknown predictor(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(PREDICTORS)}")


def make_predictors(names: Sequence[str], proto: PredictionProtocol, seed: int
                    ) -> list[NextStatePredictor]:
    """The named predictors, fresh; the LSTM views share one network."""
    check_predictors(names)
    n, out = proto.n_states, []
    lstm: LstmPredictors | None = None
    for name in names:
        if name == "regime":
            out.append(RegimePredictor(n))
        elif name == "udt":
            out.append(VaeTwinPredictor(proto, seed))
        elif name in ("lstm", "lstm-point"):
            first = lstm is None
            lstm = lstm or LstmPredictors(proto, seed)
            out.append(_View(name, lstm.softmax if name == "lstm" else lstm.point,
                             lstm.observe if first else None))
        elif name == "markov":
            out.append(CountingPredictor(name, n, None, proto.pseudo_count))
        elif name == "markov-window":
            out.append(CountingPredictor(name, n, proto.buffer_slots, proto.pseudo_count))
        elif name == "persistence":
            out.append(PersistencePredictor(n, proto.stay))
        else:
            out.append(UniformPredictor(n))
    return out


@dataclass
class PredictionScore:
    """One predictor's online scores over a sequence: sums, so runs pool exactly."""

    log_likelihood: float = 0.0      #: Σ log p(d_{k+1}), nats
    brier: float = 0.0               #: Σ Brier
    slots: int = 0                   #: predictions scored

    def add(self, probs: np.ndarray, state: int) -> None:
        self.log_likelihood += math.log(max(float(probs[state]), PROBABILITY_FLOOR))
        target = np.zeros_like(probs)
        target[state] = 1.0
        self.brier += float(((probs - target) ** 2).sum())
        self.slots += 1

    @property
    def mean_log_likelihood(self) -> float:
        return self.log_likelihood / self.slots if self.slots else math.nan

    @property
    def mean_brier(self) -> float:
        return self.brier / self.slots if self.slots else math.nan


def score_online(states: Sequence[int], predictors: Sequence[NextStatePredictor]
                 ) -> dict[str, PredictionScore]:
    """Predict, score, observe — slot by slot, every predictor on the same states. The first
    state is only observed (there is no current state to predict from before it)."""
    scores = {p.name: PredictionScore() for p in predictors}
    for k, state in enumerate(states):
        s = int(state)
        if k > 0:
            for p in predictors:
                probs = np.asarray(p.predict(), dtype=np.float64)
                if probs.shape != (probs.size,) or not np.isclose(probs.sum(), 1.0, atol=1e-4):
                    raise ValueError(f"{p.name}: prediction {probs} is not a distribution")
                scores[p.name].add(probs, s)
        for p in predictors:
            p.observe(s)
    return scores
