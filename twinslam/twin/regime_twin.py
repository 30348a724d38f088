"""The twin as exact Bayesian inference of the uplink's hidden regime.

The paper's uplink (§III, docs/architecture.md §3) is a Markov chain over N rate states whose
transition matrix P_x changes with a hidden x_t at unknown times. The variational twin
(:mod:`twinslam.twin.digital_twin`) learns q(z | d_k) from an 8-slot window; what the hidden
x_t is worth for prediction, though, lies in *how long the current regime has lasted* and
*what its transitions have been* — information far older than 8 slots. This twin infers it
exactly, by Bayesian online change-point detection (Adams & MacKay, 2007) over Markov chains:

* a hypothesis r says "the current regime began r transitions ago"; under it the regime's
  row P_x[i] has the Dirichlet posterior Dir(c_r[i] + a·m_r[i]), with c_r the transitions
  counted since then and m_r the prior's base measure (below);
* each slot a regime ends with probability H (the hazard): the hypotheses' weights grow by
  (1 − H)·p(d_{k+1} | r) and a new hypothesis takes H·p(d_{k+1} | new regime);
* H itself is unknown: a few twins with different hazards (H = 0 is whole-history counting)
  are averaged by their evidence, so the mixture settles on the hazard the uplink shows;
* what a new regime looks like is learnt: its base measure m is the transition frequency of
  the whole history up to its start (a Laplace estimate), so on real traces — where quantile
  states make staying put likely in every regime — a new regime does not start from uniform.

The posterior over the current regime's matrix is this twin's latent: μ = E[P], Σ = Var[P]
(elementwise, N² each), and p(d_{k+1}) is the posterior predictive. Everything is a filter
update per slot (O(hypotheses·N) work, no training), so ``observe`` never asks for a retrain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from twinslam.twin.latent import latent_features
from twinslam.twin.rate_model import Latent


@dataclass(frozen=True)
class RegimeConfig:
    n_states: int = 2
    #: one filter per hazard (probability that a regime ends at a slot); 0 = never
    hazards: tuple[float, ...] = (0.0, 1 / 3000, 1 / 1000, 1 / 300, 1 / 100, 1 / 30)
    #: a: pseudo-transitions per row a new regime's prior holds (N / 2 = KT on uniform m)
    prior_strength: float | None = None
    max_hypotheses: int = 200         #: run lengths kept per filter (the likeliest)
    prune_below: float = 1e-9         #: a hypothesis lighter than this × the heaviest goes

    def __post_init__(self) -> None:
        if self.n_states < 1:
            raise ValueError(f"n_states must be >= 1, got {self.n_states}")
        if not self.hazards or any(not 0.0 <= h < 1.0 for h in self.hazards):
            raise ValueError(f"hazards must be a non-empty list in [0, 1), got {self.hazards}")
        if self.max_hypotheses < 1:
            raise ValueError("max_hypotheses must be >= 1")
        if self.prior_strength is not None and not self.prior_strength > 0:
            raise ValueError(f"prior_strength must be > 0, got {self.prior_strength}")

    @property
    def strength(self) -> float:
        return self.n_states / 2 if self.prior_strength is None else self.prior_strength


@dataclass
class _Filter:
    """Run-length posterior of one hazard: per hypothesis its counts, base measure, weight."""

    hazard: float
    counts: np.ndarray            #: (R, N, N) transitions since the hypothesis' start
    base: np.ndarray              #: (R, N, N) rows of the prior's base measure at its start
    weights: np.ndarray           #: (R,) posterior, sums to 1
    log_evidence: float = 0.0     #: log p(everything observed | this hazard)


@dataclass
class RegimeTwin:
    """Online posterior over the current regime of a piecewise-stationary Markov chain; a
    :class:`~twinslam.twin.rate_model.Twin` and a filter (``online``: reset per run). Its
    features are [μ, log Σ] of the posterior over the current regime's matrix (2·N² numbers),
    its artificial next states drawn from the posterior predictive."""

    name = "regime"
    online = True

    config: RegimeConfig = field(default_factory=RegimeConfig)
    version: int = 0                     #: = slots: the posterior changes every slot
    state: int | None = None             #: the newest state observed
    slots: int = 0                       #: states observed
    _global: np.ndarray = field(init=False, repr=False)
    _filters: list[_Filter] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.reset()

    @property
    def n_states(self) -> int:
        return self.config.n_states

    @property
    def feature_size(self) -> int:
        return 2 * self.config.n_states * self.config.n_states

    def describe(self) -> str:
        hazards = ", ".join(f"{h:.3g}" for h in self.config.hazards)
        return f"Bayesian regime twin (hazards {hazards})"

    def reset(self) -> None:
        """Forget everything (a new run)."""
        n = self.config.n_states
        self._global = np.zeros((n, n))
        base = self._base()[None]
        self._filters = [_Filter(h, np.zeros((1, n, n)), base.copy(), np.ones(1))
                         for h in self.config.hazards]
        self.state, self.slots, self.version = None, 0, 0

    def _base(self) -> np.ndarray:
        """The base measure a regime starting now gets: Laplace-smoothed global frequencies."""
        n = self.config.n_states
        return np.asarray((self._global + 1.0) / (self._global.sum(axis=1, keepdims=True) + n))

    # -- the filter update -------------------------------------------------------------------

    def observe(self, state: int) -> bool:
        """Slot k's state; updates every hypothesis. Returns False: nothing ever needs a
        retrain (the same answer as a learned twin between retrains)."""
        s = int(state)
        if not 0 <= s < self.config.n_states:
            raise ValueError(f"state {s} outside [0, {self.config.n_states})")
        prev, self.state = self.state, s
        self.slots += 1
        self.version = self.slots
        if prev is None:
            return False
        a, base_now = self.config.strength, self._base()
        for f in self._filters:
            grow = f.weights * (1.0 - f.hazard) * _predictive(f, prev, a)[:, s]
            fresh = f.hazard * base_now[prev, s]
            evidence = float(grow.sum() + fresh)
            f.log_evidence += np.log(evidence)
            f.counts[:, prev, s] += 1.0
            if f.hazard > 0.0:
                first = np.zeros((1, *base_now.shape))
                first[0, prev, s] = 1.0
                f.counts = np.concatenate([first, f.counts])
                f.base = np.concatenate([base_now[None], f.base])
                grow = np.concatenate([[fresh], grow])
            f.weights = grow / evidence
            self._prune(f)
        self._global[prev, s] += 1.0
        return False

    def retrain(self) -> list[float]:
        """Nothing to fit: the posterior is always up to date."""
        return []

    def _prune(self, f: _Filter) -> None:
        keep = np.flatnonzero(f.weights >= self.config.prune_below * f.weights.max())
        if keep.size > self.config.max_hypotheses:
            keep = np.sort(keep[np.argsort(f.weights[keep])[-self.config.max_hypotheses:]])
        if keep.size < f.weights.size:
            f.counts, f.base, f.weights = f.counts[keep], f.base[keep], f.weights[keep]
            f.weights = f.weights / f.weights.sum()

    # -- what the posterior says -------------------------------------------------------------

    def hazard_weights(self) -> np.ndarray:
        """Posterior probability of each configured hazard (uniform prior over them)."""
        log_e = np.array([f.log_evidence for f in self._filters])
        w = np.exp(log_e - log_e.max())
        return np.asarray(w / w.sum())

    def predict(self, history: Sequence[int] = ()) -> np.ndarray:
        """p(d_{k+1} | everything observed), from the newest state of ``history`` (the newest
        observed when it is empty)."""
        s = self._current(history[-1] if len(history) else None)
        a, base_now = self.config.strength, self._base()
        out = np.zeros(self.config.n_states)
        for pi, f in zip(self.hazard_weights(), self._filters, strict=True):
            row = f.weights @ _predictive(f, s, a)
            out += pi * ((1.0 - f.hazard) * row + f.hazard * base_now[s])
        return np.asarray(out / out.sum())

    def transition_matrix(self) -> np.ndarray:
        """E[P_x | observed] of the current regime (rows: current state)."""
        return self._moments()[0]

    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and elementwise variance of the current regime's matrix under the posterior
        (a mixture of Dirichlet rows over hypotheses and hazards)."""
        a = self.config.strength
        mean = np.zeros((self.config.n_states,) * 2)
        second = np.zeros_like(mean)
        for pi, f in zip(self.hazard_weights(), self._filters, strict=True):
            alpha = f.counts + a * f.base                           # (R, N, N)
            total = alpha.sum(axis=2, keepdims=True)
            m = alpha / total
            var = m * (1.0 - m) / (total + 1.0)
            mean += pi * np.einsum("r,rij->ij", f.weights, m)
            second += pi * np.einsum("r,rij->ij", f.weights, var + m * m)
        return mean, np.clip(second - mean * mean, 0.0, None)

    def latent(self) -> Latent:
        """μ = E[P] and Σ = Var[P] flattened (N² each), p(d_{k+1}), and the slot count as the
        model version."""
        mean, var = self._moments()
        return Latent(mean.ravel().copy(), var.ravel().copy(), self.predict(), self.version)

    def features(self, history: Sequence[int] = ()) -> np.ndarray:
        """[μ, log Σ] of the posterior (the history is the filter's own)."""
        lat = self.latent()
        return latent_features(lat.mu, lat.sigma)

    def sample_next(self, history: Sequence[int], count: int, rng: np.random.Generator
                    ) -> np.ndarray:
        """``count`` draws of d̂_{k+1} after the newest state of ``history`` for artificial
        experiences: a hazard and a hypothesis by their posterior, a row from its Dirichlet,
        the next state from the row."""
        s = self._current(history[-1] if len(history) else None)
        a = self.config.strength
        pis = self.hazard_weights()
        out = np.empty(count, dtype=np.int64)
        for n in range(count):
            f = self._filters[int(rng.choice(len(pis), p=pis))]
            r = int(rng.choice(f.weights.size, p=f.weights))
            row = rng.dirichlet(f.counts[r, s] + a * f.base[r, s])
            out[n] = int(rng.choice(self.config.n_states, p=row / row.sum()))
        return out

    def state_dict(self) -> dict[str, Any]:
        """The configuration (a filter has no weights: a run starts from the prior)."""
        cfg = self.config
        return {"n_states": cfg.n_states, "hazards": [float(h) for h in cfg.hazards],
                "prior_strength": cfg.prior_strength, "max_hypotheses": cfg.max_hypotheses}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> RegimeTwin:
        return cls(RegimeConfig(
            n_states=int(blob["n_states"]), hazards=tuple(float(h) for h in blob["hazards"]),
            prior_strength=(None if blob["prior_strength"] is None
                            else float(blob["prior_strength"])),
            max_hypotheses=int(blob["max_hypotheses"])))

    def expected_run_length(self) -> float:
        """Posterior mean of the transitions the current regime has lasted."""
        return float(sum(pi * (f.weights @ f.counts.sum(axis=(1, 2)))
                         for pi, f in zip(self.hazard_weights(), self._filters, strict=True)))

    def _current(self, state: int | None) -> int:
        s = self.state if state is None else int(state)
        if s is None:
            return 0
        if not 0 <= s < self.config.n_states:
            raise ValueError(f"state {s} outside [0, {self.config.n_states})")
        return s


def _predictive(f: _Filter, state: int, strength: float) -> np.ndarray:
    """(R, N): each hypothesis' posterior predictive row for the current ``state``."""
    alpha = f.counts[:, state] + strength * f.base[:, state]
    return np.asarray(alpha / alpha.sum(axis=1, keepdims=True))
