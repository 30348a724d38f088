"""The variational twin: the paper's user digital twin of the uplink (§V, Algorithm 1;
docs/architecture.md §3), a :class:`~twinslam.twin.rate_model.Twin` named ``variational``.

The rate's transition matrix changes with a hidden x_t across intervals. The twin learns it by
deep variational inference, as VariBAD does for a task's hidden parameters: an encoder reads
the rate history d_k and outputs a Gaussian q(z | d_k) = N(μ, diag Σ) over a Z-dimensional
latent; a decoder reads the newest state of d_k with a sample z̃ (reparametrisation trick) and
outputs the distribution of d_{k+1}. Training maximises the ELBO of eq. (18)/(22):

    E_q[log q(d_{k+1} | d_k, z)] − KL(q(z | d_k) ‖ N(0, I)).

Only the newest state of d_k enters the decoder (the chain is Markov within an interval), so
whatever the history says about the interval has to pass through z; with z = μ the decoder's
rows, one per current state, are the twin's estimate of the current interval's matrix. μ and
Σ are the latent features the policy's state is augmented with.
"""

from __future__ import annotations

import copy
import io
import pickle
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from twinslam.twin.latent import latent_features
from twinslam.twin.rate_history import fit, history_windows, latest_window
from twinslam.twin.rate_model import Latent


@dataclass(frozen=True)
class VariationalConfig:
    n_states: int = 2
    latent_dim: int = 8           #: Z
    history: int = 8              #: τ + 1 states in d_k
    lstm_hidden: int = 300        #: paper: 2 × LSTM(300)
    buffer_slots: int = 600       #: real experiences a retrain learns from (the latest)
    retrain_every: int = 100      #: W
    steps_per_retrain: int = 100  #: Adam steps per retrain (warm-started)
    batch_size: int = 64
    learning_rate: float = 3e-3
    kl_weight: float = 1.0        #: 1 is the ELBO; kept as a knob for ablations
    seed: int = 0


class VariationalNetwork(nn.Module):
    """Encoder 2×LSTM(300) → FC(256, 128, 128, 32) → (μ, log Σ); decoder
    FC(256, 128, 64, 16) on [newest state, z] → logits over the N next states."""

    def __init__(self, n_states: int, latent_dim: int, lstm_hidden: int = 300) -> None:
        super().__init__()
        self.n_states, self.latent_dim = n_states, latent_dim
        self.lstm = nn.LSTM(n_states, lstm_hidden, num_layers=2, batch_first=True)
        self.encoder = _mlp(lstm_hidden, (256, 128, 128, 32))
        self.mu = nn.Linear(32, latent_dim)
        self.log_var = nn.Linear(32, latent_dim)
        self.decoder = nn.Sequential(_mlp(n_states + latent_dim, (256, 128, 64, 16)),
                                     nn.Linear(16, n_states))

    def encode(self, windows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ, log Σ) of q(z | d_k) for windows (B, τ+1, N)."""
        out, _ = self.lstm(windows)
        h = self.encoder(out[:, -1])
        return self.mu(h), self.log_var(h).clamp(-10.0, 10.0)

    def decode(self, current: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Logits of d_{k+1} given the one-hot current state (B, N) and z (B, Z)."""
        logits: torch.Tensor = self.decoder(torch.cat([current, z], dim=-1))
        return logits

    def negative_elbo(self, windows: torch.Tensor, targets: torch.Tensor, kl_weight: float
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(loss, reconstruction NLL, KL), batch means; z̃ = μ + σ·ε (reparametrisation)."""
        mu, log_var = self.encode(windows)
        z = mu + torch.exp(0.5 * log_var) * torch.randn_like(mu)
        nll = nn.functional.cross_entropy(self.decode(windows[:, -1], z), targets)
        kl = 0.5 * (torch.exp(log_var) + mu * mu - 1.0 - log_var).sum(dim=-1).mean()
        return nll + kl_weight * kl, nll, kl


def _mlp(n_in: int, widths: tuple[int, ...]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(n_in, w), nn.ReLU()]
        n_in = w
    return nn.Sequential(*layers)


class VariationalTwin:
    """Real-experience buffer + UDT network, retrained every W slots (Algorithm 1).

    ``observe`` appends a slot's state; ``retrain`` fits the network to the latest
    ``buffer_slots`` states, warm-started from the current weights; the queries use the latest
    history. Training and querying never share a network: ``train_copy`` / ``adopt`` let a node
    train in a background thread and swap the result in. Learned weights (not ``online``):
    they carry over from run to run.
    """

    name = "variational"
    online = False

    def __init__(self, config: VariationalConfig | None = None) -> None:
        self.config = config or VariationalConfig()
        torch.manual_seed(self.config.seed)
        self._rng = np.random.default_rng(self.config.seed)
        self.network = VariationalNetwork(self.config.n_states, self.config.latent_dim,
                                  self.config.lstm_hidden)
        self.states: list[int] = []
        self.version = 0
        self._since = 0                        #: slots observed since the last retrain

    @property
    def n_states(self) -> int:
        return self.config.n_states

    @property
    def feature_size(self) -> int:
        """[μ, log Σ]: 2 Z."""
        return 2 * self.config.latent_dim

    def reset(self) -> None:
        """Nothing: the learned weights carry over from run to run."""

    def describe(self) -> str:
        cfg = self.config
        return (f"variational twin, Z = {cfg.latent_dim}, retrain every "
                f"{cfg.retrain_every} slots")

    # -- data ----------------------------------------------------------------------------

    def observe(self, state: int) -> bool:
        """Record slot k's state; True when W new slots have arrived since the last retrain."""
        if not 0 <= int(state) < self.config.n_states:
            raise ValueError(f"state {state} outside [0, {self.config.n_states})")
        self.states.append(int(state))
        del self.states[:-max(self.config.buffer_slots, self.config.history) - 1]
        self._since += 1
        return self._since >= self.config.retrain_every

    # -- training ------------------------------------------------------------------------

    def retrain(self, steps: int | None = None) -> list[float]:
        """Fit to the buffer in place; returns the negative ELBO of every step."""
        trained, trace = self.train_copy(self.take_training_data(), steps)
        self.adopt(trained, trace)
        return trace

    def take_training_data(self) -> list[int]:
        """The buffer as it is now, for a retrain; the W-slot count starts again."""
        self._since = 0
        return list(self.states)

    def train_copy(self, states: list[int], steps: int | None = None
                   ) -> tuple[VariationalNetwork, list[float]]:
        """A copy of the network trained on ``states`` (the live one keeps answering
        meanwhile, so a node can run this on another thread)."""
        cfg = self.config
        windows, targets = history_windows(np.array(states), cfg.history, cfg.n_states)
        net = copy.deepcopy(self.network)
        if len(targets) == 0:
            return net, []
        trace = fit(net, lambda w, t: net.negative_elbo(w, t, cfg.kl_weight)[0], windows,
                    targets, cfg.steps_per_retrain if steps is None else steps,
                    cfg.batch_size, cfg.learning_rate, self._rng)
        return net, trace

    def adopt(self, network: VariationalNetwork, trace: list[float]) -> None:
        """Make a trained network the live one (a new model version)."""
        self.network = network
        self.version += 1

    # -- queries -------------------------------------------------------------------------

    def _window(self, states: Sequence[int] | None = None) -> torch.Tensor:
        return latest_window(self.states if states is None else states, self.config.history,
                             self.config.n_states)

    @torch.no_grad()
    def latent(self, states: Sequence[int] | None = None) -> Latent:
        """μ, Σ and p(d_{k+1}) from the latest history (or ``states``); the prediction uses
        z = μ."""
        window = self._window(states)
        mu, log_var = self.network.encode(window)
        probs = torch.softmax(self.network.decode(window[:, -1], mu), dim=-1)
        return Latent(mu[0].numpy().copy(), torch.exp(log_var)[0].numpy().copy(),
                      probs[0].numpy().copy(), self.version)

    def predict(self, history: Sequence[int]) -> np.ndarray:
        """p(d_{k+1}) from the decoder with z = μ(``history``)."""
        return self.latent(history).next_state_probs.astype(np.float64)

    def features(self, history: Sequence[int]) -> np.ndarray:
        """[μ, log Σ] of q(z | d_k): VariBAD gives the policy the posterior's parameters."""
        lat = self.latent(history)
        return latent_features(lat.mu, lat.sigma)

    @torch.no_grad()
    def transition_matrix(self, states: Sequence[int] | None = None) -> np.ndarray:
        """The current interval's estimated matrix: row i = decoder(state i, z = μ(d_k))."""
        n = self.config.n_states
        mu, _ = self.network.encode(self._window(states))
        rows = self.network.decode(torch.eye(n), mu.expand(n, -1))
        return torch.softmax(rows, dim=-1).numpy().astype(np.float64)

    @torch.no_grad()
    def sample_next(self, history: Sequence[int], count: int,
                    rng: np.random.Generator | None = None) -> np.ndarray:
        """``count`` samples d̂_{k+1} for artificial experiences: z̃ ~ q(z | d_k) each, then
        d̂ ~ decoder(d_k, z̃); d_k is ``history``."""
        rng = rng or self._rng
        window = self._window(history)
        mu, log_var = self.network.encode(window)
        eps = torch.from_numpy(rng.standard_normal((count, mu.shape[1])).astype(np.float32))
        z = mu + torch.exp(0.5 * log_var) * eps
        probs = torch.softmax(self.network.decode(window[:, -1].expand(count, -1), z), dim=-1)
        cum = probs.numpy().cumsum(axis=1)
        u = rng.random((count, 1))
        return np.asarray(np.minimum((u > cum).sum(axis=1), self.config.n_states - 1))

    # -- persistence ---------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """What a policy checkpoint stores: config, weights and version (not the buffer)."""
        return {"config": self.config.__dict__, "network": self.network.state_dict(),
                "version": self.version}

    @classmethod
    def from_state_dict(cls, blob: dict[str, Any]) -> VariationalTwin:
        twin = cls(VariationalConfig(**blob["config"]))
        twin.network.load_state_dict(blob["network"])
        twin.version = int(blob["version"])
        return twin

    def save(self, path: Path) -> None:
        """Weights, config, version and the buffer, in one torch file (written atomically)."""
        path = Path(path)
        buf = io.BytesIO()
        torch.save({"config": self.config.__dict__, "state_dict": self.network.state_dict(),
                    "version": self.version, "states": self.states}, buf)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_bytes(buf.getvalue())
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> VariationalTwin:
        path = Path(path)
        try:
            blob = torch.load(path, map_location="cpu", weights_only=True)
            twin = cls(VariationalConfig(**blob["config"]))
            twin.network.load_state_dict(blob["state_dict"])
        except (OSError, RuntimeError, KeyError, TypeError, EOFError,
                pickle.UnpicklingError) as exc:
            raise ValueError(f"{path}: not a twin checkpoint ({exc})") from None
        twin.network.eval()
        twin.version = int(blob["version"])
        twin.states = [int(s) for s in blob["states"]]
        return twin
