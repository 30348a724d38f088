"""Every rate model by name: what ``twinslam train --rate-model`` and ``twinslam experiment
twin-predict --predictor`` accept, how a policy checkpoint's model is rebuilt, and which of
them the twin node can run.

The learned models (the variational twin, the LSTM) need torch: they are imported when one of
them is asked for, so a caller on the regime twin or the counts never loads it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from twinslam.twin.markov import MarkovCounts
from twinslam.twin.naive import Persistence, Uniform
from twinslam.twin.rate_model import RateModel
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin

#: what can drive a learned policy (paper §VII: the twin, the LSTM, the Markov estimator;
#: the regime twin, the best predictor measured, is the default)
POLICY_RATE_MODELS = ("regime", "variational", "lstm", "markov")
DEFAULT_RATE_MODEL = "regime"
#: what the prediction experiment can score: those, and the baselines every model must beat
PREDICTORS = ("regime", "variational", "lstm", "lstm-point", "markov", "markov-window",
              "persistence", "uniform")
#: the models the twin node runs (a policy on one of them can take the node's latent)
TWIN_MODELS = ("regime", "variational")
#: old names still accepted (``udt`` named the variational twin before the twins were told apart)
ALIASES = {"udt": "variational"}


@dataclass(frozen=True)
class RateModelSettings:
    """How a model is built: the twin node's and the trainer's defaults."""

    n_states: int = 2
    retrain_every: int = 100      #: W, slots between retrains of a learned model
    buffer_slots: int = 600       #: the learned models' buffer; also markov-window's window
    history: int = 8              #: τ + 1, the networks' input window
    steps_per_retrain: int = 100  #: Adam steps per retrain of the networks
    seed: int = 0                 #: the networks' initialisation and training
    stay: float = 0.9             #: persistence's probability of staying put
    pseudo_count: float = 0.0     #: the counts' Dirichlet smoothing (0: the paper's MLE)
    point_epsilon: float = 0.05   #: what lstm-point's prediction leaves for the other states


def canonical(name: str) -> str:
    """The name a model goes by (an alias resolved)."""
    return ALIASES.get(name, name)


def check_names(names: Sequence[str], allowed: Sequence[str] = PREDICTORS) -> None:
    """ValueError naming what is not one of ``allowed`` (without building any network)."""
    unknown = sorted({n for n in names if canonical(n) not in allowed})
    if unknown:
        raise ValueError(f"unknown rate model(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(allowed)}")


def make_rate_model(name: str, settings: RateModelSettings = RateModelSettings()
                    ) -> RateModel:
    """A fresh model called ``name`` (any of :data:`PREDICTORS` or an alias)."""
    check_names([name])
    s, kind = settings, canonical(name)
    if kind == "regime":
        return RegimeTwin(RegimeConfig(n_states=s.n_states))
    if kind in ("markov", "markov-window"):
        return MarkovCounts(s.n_states, s.buffer_slots if kind == "markov-window" else None,
                            s.pseudo_count)
    if kind == "persistence":
        return Persistence(s.n_states, s.stay)
    if kind == "uniform":
        return Uniform(s.n_states)
    if kind == "variational":
        from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin

        return VariationalTwin(VariationalConfig(
            n_states=s.n_states, history=s.history, buffer_slots=s.buffer_slots,
            retrain_every=s.retrain_every, steps_per_retrain=s.steps_per_retrain, seed=s.seed))
    from twinslam.twin.lstm import LstmConfig, LstmPredictor

    return LstmPredictor(LstmConfig(
        n_states=s.n_states, history=s.history, buffer_slots=s.buffer_slots,
        retrain_every=s.retrain_every, steps_per_retrain=s.steps_per_retrain, seed=s.seed,
        point_epsilon=s.point_epsilon if kind == "lstm-point" else None))


def make_rate_models(names: Sequence[str], settings: RateModelSettings) -> list[RateModel]:
    """Several fresh models, all checked before any is built."""
    check_names(names)
    return [make_rate_model(name, settings) for name in names]


def load_rate_model(name: str, blob: dict[str, Any]) -> RateModel:
    """The model a policy checkpoint stored (``state_dict``) under ``name``."""
    kind = canonical(name)
    check_names([kind], POLICY_RATE_MODELS)
    if kind == "regime":
        return RegimeTwin.from_state_dict(blob)
    if kind == "markov":
        return MarkovCounts.from_state_dict(blob)
    if kind == "variational":
        from twinslam.twin.variational_twin import VariationalTwin

        return VariationalTwin.from_state_dict(blob)
    from twinslam.twin.lstm import LstmPredictor

    return LstmPredictor.from_state_dict(blob)
