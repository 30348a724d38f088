"""udt_node: the user digital twin as a ROS 2 node (paper §V, Algorithm 1).

Subscribes ``device/uplink_throughput`` (``twinslam_msgs/UplinkThroughput``, one per slot),
quantises the achieved throughput to the nearest of N rates spread over [``rate_min``,
``rate_max``] and publishes ``udt/rate_latent`` (``RateLatent``: μ, Σ, p(d_{k+1}), model
version) for every slot, from one of two twins (``model``):

* ``regime`` (default): the Bayesian regime twin (:mod:`twinslam.twin.regime_twin`), a filter
  updated every slot — μ, Σ are the mean and variance of the current regime's N×N matrix, the
  version counts the slots it has seen. It predicts the next state best of the models measured
  (docs/results.md, "twin-predict").
* ``udt``: the paper's variational twin. It keeps the real-experience buffer; every
  ``retrain_every`` slots it is retrained on a background thread, warm-started; callbacks never
  wait for it, and the trained network is swapped in when ready (the executor's callbacks and
  the training thread share only the swap, under a lock). With ``weights`` set, it is loaded
  from that file at start (if present) and saved after every retrain.

With ``policy_checkpoint`` set to a twin-driven AMM policy (``twinslam train --rate-model
regime|udt``), the node runs that policy's twin — its model and its configuration (the
variational twin: its weights) — so the latents the edge feeds it mean what they meant in
training; ``model`` is then not consulted.

A throughput that is NaN, infinite or negative (refused by the message validation of
:mod:`msg_schemas.validation`) or above ``max_mbps`` (refused here) is logged as an error,
counted, and left out of the buffer.
"""

from __future__ import annotations

import math
import sys
import threading
from pathlib import Path

import numpy as np
import torch
from rclpy.node import Node
from twinslam_msgs.msg import RateLatent, UplinkThroughput

from msg_schemas import new, qos, topics
from twinslam.common import table1
from twinslam.node_hosts.checked_subscription import CheckedSubscription
from twinslam.node_hosts.node_main import NodeStartError, run_node
from twinslam.node_hosts.parameters import ParamSpec, declare
from twinslam.twin.digital_twin import Latent, TwinConfig, UserDigitalTwin
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin
from twinslam.uplink.quantiser import RateQuantiser

MODELS = ("regime", "udt")

PARAMETERS = (
    ParamSpec("model", "regime", "regime (Bayesian regime twin) or udt (variational twin)",
              check=lambda v: None if v in MODELS else f"must be one of {', '.join(MODELS)}"),
    ParamSpec("states", 2, "N uplink states, spread over [rate_min, rate_max]", low=1, high=64),
    ParamSpec("latent_dim", 8, "udt: Z, the latent's dimensions", low=1, high=1024),
    ParamSpec("history", 8, "udt: tau + 1 slots of rate history the encoder reads", low=1,
              high=10_000),
    ParamSpec("retrain_every", 100, "udt: W, slots between retrains (background thread)",
              low=1, high=1_000_000),
    ParamSpec("buffer_slots", 600, "udt: real experiences a retrain learns from", low=1,
              high=10_000_000),
    ParamSpec("steps_per_retrain", 100, "udt: optimiser steps per retrain", low=1,
              high=1_000_000),
    ParamSpec("rate_min", table1.RATE_MIN_MBPS, "Mbit/s of the lowest state", low=0.0, high=1e6),
    ParamSpec("rate_max", table1.RATE_MAX_MBPS, "Mbit/s of the highest state", low=0.0, high=1e6),
    ParamSpec("max_mbps", 10_000.0, "a larger throughput report is refused as absurd",
              low=0.0, high=1e9),
    ParamSpec("weights", "", "udt: file to load at start and save after each retrain"),
    ParamSpec("seed", 0, "udt: seed of the twin's training", low=0),
    ParamSpec("policy_checkpoint", "", "run the twin of this AMM policy (rate model regime or "
              "udt) instead of model"),
)


class TwinNode(Node):
    """Topic ↔ twin wiring; the learning lives in
    :class:`~twinslam.twin.digital_twin.UserDigitalTwin`."""

    def __init__(self) -> None:
        super().__init__("udt_node")
        p = declare(self, PARAMETERS)
        config = TwinConfig(n_states=int(p["states"]), latent_dim=int(p["latent_dim"]),
                            history=int(p["history"]), retrain_every=int(p["retrain_every"]),
                            buffer_slots=int(p["buffer_slots"]),
                            steps_per_retrain=int(p["steps_per_retrain"]), seed=int(p["seed"]))
        #: a measured rate's state: the nearest of N rates spread over [rate_min, rate_max]
        self.quantiser = RateQuantiser.evenly(config.n_states, float(p["rate_min"]),
                                              float(p["rate_max"]))
        self.rates = self.quantiser.rates
        self.max_mbps = float(p["max_mbps"])
        self.weights = Path(p["weights"]) if p["weights"] else None
        try:
            self.twin = self._load_or_create(config, str(p["model"]),
                                             str(p["policy_checkpoint"]))
        except (ValueError, OSError) as exc:
            raise NodeStartError(str(exc)) from None
        if self.twin.config.n_states != config.n_states:
            raise NodeStartError(f"a {self.twin.config.n_states}-state twin, states:="
                                 f"{config.n_states} asked for")
        self.rejected = 0
        self.received = 0
        self._lock = threading.Lock()            # guards the twin's network swap
        self._training: threading.Thread | None = None
        self.pub = self.create_publisher(RateLatent, topics.RATE_LATENT, qos.PROTOCOL)
        self.sub = CheckedSubscription(self, UplinkThroughput, topics.UPLINK_THROUGHPUT,
                                       self._on_throughput, qos.PROTOCOL)

    def _load_or_create(self, config: TwinConfig, model: str, policy_checkpoint: str
                        ) -> UserDigitalTwin | RegimeTwin:
        log = self.get_logger()
        if policy_checkpoint:
            from twinslam.mbrl.policy import MbrlPolicy
            from twinslam.twin.rate_models import RegimeRateModel, TwinRateModel

            policy = MbrlPolicy(Path(policy_checkpoint))
            if isinstance(policy.rate_model, RegimeRateModel):
                log.info(f"the regime twin of policy {policy_checkpoint}")
                return RegimeTwin(policy.rate_model.twin.config)
            if not isinstance(policy.rate_model, TwinRateModel):
                raise ValueError(f"{policy_checkpoint}: a {policy.rate_model_name}-driven "
                                 "policy has no twin to start from")
            log.info(f"the twin of policy {policy_checkpoint} (version "
                     f"{policy.rate_model.twin.version})")
            return policy.rate_model.twin
        if model == "regime":
            if self.weights is not None:
                log.warning("weights is for model:=udt; the regime twin has none (ignored)")
            return RegimeTwin(RegimeConfig(n_states=config.n_states))
        if self.weights is not None and self.weights.is_file():
            twin = UserDigitalTwin.load(self.weights)
            log.info(f"loaded twin version {twin.version} ({len(twin.states)} slots) from "
                     f"{self.weights}")
            return twin
        return UserDigitalTwin(config)

    def describe(self) -> str:
        """What the twin is, for the start-up line."""
        if isinstance(self.twin, RegimeTwin):
            hazards = ", ".join(f"{h:.3g}" for h in self.twin.config.hazards)
            return f"Bayesian regime twin (hazards {hazards})"
        cfg = self.twin.config
        return (f"variational twin, Z = {cfg.latent_dim}, retrain every "
                f"{cfg.retrain_every} slots")

    def quantise(self, mbps: float) -> int:
        """Index of the state rate nearest to a measured throughput."""
        return self.quantiser.state(mbps)

    def _on_throughput(self, msg: UplinkThroughput) -> None:
        mbps = float(msg.achieved_mbps)
        if not math.isfinite(mbps) or mbps < 0 or mbps > self.max_mbps:
            self.rejected += 1
            self.get_logger().error(
                f"slot {msg.slot}: refused throughput {mbps!r} Mbit/s (must be finite, >= 0 and "
                f"<= max_mbps {self.max_mbps:g}); {self.refused} refused so far")
            return
        self.received += 1
        due = self.twin.observe(self.quantise(mbps))
        if due and self._training is None and isinstance(self.twin, UserDigitalTwin):
            data = self.twin.take_training_data()
            self._training = threading.Thread(target=self._retrain, args=(data,),
                                              name="udt-retrain", daemon=True)
            self._training.start()
        with self._lock:
            latent: Latent = self.twin.latent()
        out = new(RateLatent, slot=int(msg.slot),
                  model_version=latent.model_version,
                  mu=latent.mu.astype(np.float32), sigma=latent.sigma.astype(np.float32),
                  next_state_probs=latent.next_state_probs.astype(np.float32),
                  state_rates_mbps=self.rates.astype(np.float64))
        out.header.stamp = msg.header.stamp
        out.header.frame_id = msg.header.frame_id
        self.pub.publish(out)

    def _retrain(self, states: list[int]) -> None:
        """Runs on the training thread: train a copy, swap it in, save it."""
        log = self.get_logger()
        try:
            network, trace = self.twin.train_copy(states)
            with self._lock:
                self.twin.adopt(network, trace)
                if self.weights is not None:
                    self.twin.save(self.weights)
            if trace:
                log.info(f"retrained on {len(states)} slots: model version "
                         f"{self.twin.version}, negative ELBO {trace[0]:.3f} -> {trace[-1]:.3f}")
        except Exception as exc:  # a failed retrain must not kill the node
            log.error(f"retrain failed, keeping model version {self.twin.version}: {exc}")
        finally:
            self._training = None

    @property
    def refused(self) -> int:
        """Throughput samples refused: malformed or non-finite/negative (dropped by the
        runtime's validation before the callback) plus absurd ones (refused here)."""
        return self.rejected + self.sub.rejected

    def wait_for_training(self, timeout: float) -> None:
        thread = self._training
        if thread is not None:
            thread.join(timeout)

    def close(self) -> None:
        """At shutdown: let a running retrain finish (and save), then say what was learnt."""
        self.wait_for_training(30.0)
        self.get_logger().info(f"stopping: {self.received} slots learned from, "
                               f"{self.refused} refused")


def main(args: list[str] | None = None) -> int:
    # One intra-op thread: the retrain shares the machine with the spin thread (and on the
    # edge host with the other nodes), and the per-slot inference is tiny.
    torch.set_num_threads(1)

    def started(twin_node: TwinNode) -> None:
        twin_node.get_logger().info(
            f"{twin_node.describe()} of {twin_node.rates.size} uplink states "
            f"{twin_node.rates.tolist()} Mbit/s; listening on {twin_node.sub.topic_name}")

    return run_node("udt_node", TwinNode, args, started=started)


if __name__ == "__main__":
    sys.exit(main())
