"""udt_node: the user digital twin as a ROS 2 node (paper §V, Algorithm 1).

Subscribes ``/device/uplink_throughput`` (``twinslam_msgs/UplinkThroughput``, one per slot),
quantises the achieved throughput to the nearest of N rates spread over [``rate_min``,
``rate_max``], keeps the real-experience buffer and publishes ``/udt/rate_latent``
(``RateLatent``: μ, Σ, p(d_{k+1}), model version) for every slot. Every ``retrain_every`` slots
the twin is retrained on a background thread, warm-started; callbacks never wait for it, and
the trained network is swapped in when ready. With ``weights`` set, the twin is loaded from
that file at start (if present) and saved after every retrain. With ``policy_checkpoint`` set
to a twin-driven AMM policy (``twinslam train --rate-model udt``), the twin starts as the one that
policy was trained with, so the latents the edge feeds it mean what they meant in training.

A throughput that is NaN, infinite or negative (refused by the message validation of
:mod:`msg_schemas.validation`) or above ``max_mbps`` (refused here) is logged as an error,
counted, and left out of the buffer.
"""

from __future__ import annotations

import math
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import torch

import node_runtime
from msg_schemas.registry import new
from node_runtime import PROTOCOL
from udt_node.channel import state_rates
from udt_node.twin import TwinConfig, UserDigitalTwin

PARAMETERS = {"states": 2, "latent_dim": 8, "history": 8, "retrain_every": 100,
              "buffer_slots": 600, "steps_per_retrain": 100, "rate_min": 40.0,
              "rate_max": 80.0, "max_mbps": 10_000.0, "weights": "", "seed": 0,
              "policy_checkpoint": ""}
THROUGHPUT_TOPIC = "/device/uplink_throughput"
LATENT_TOPIC = "/udt/rate_latent"


class TwinNode:
    """Topic ↔ twin wiring; the learning lives in :class:`~udt_node.twin.UserDigitalTwin`."""

    def __init__(self, node: node_runtime.Node) -> None:
        self.node = node
        p = {k: node.get_parameter(k).value for k in PARAMETERS}
        config = TwinConfig(n_states=int(p["states"]), latent_dim=int(p["latent_dim"]),
                            history=int(p["history"]), retrain_every=int(p["retrain_every"]),
                            buffer_slots=int(p["buffer_slots"]),
                            steps_per_retrain=int(p["steps_per_retrain"]), seed=int(p["seed"]))
        self.rates = state_rates(config.n_states, float(p["rate_min"]), float(p["rate_max"]))
        self.max_mbps = float(p["max_mbps"])
        self.weights = Path(p["weights"]) if p["weights"] else None
        self.twin = self._load_or_create(config, str(p["policy_checkpoint"]))
        if self.twin.config.n_states != config.n_states:
            raise ValueError(f"a {self.twin.config.n_states}-state twin, states:="
                             f"{config.n_states} asked for")
        self.rejected = 0
        self.received = 0
        self._lock = threading.Lock()            # guards the twin's network swap
        self._training: threading.Thread | None = None
        self.pub = node.create_publisher("twinslam_msgs/msg/RateLatent", LATENT_TOPIC, PROTOCOL)
        self.sub = node.create_subscription("twinslam_msgs/msg/UplinkThroughput",
                                            THROUGHPUT_TOPIC, self._on_throughput, PROTOCOL)

    def _load_or_create(self, config: TwinConfig, policy_checkpoint: str) -> UserDigitalTwin:
        log = self.node.get_logger()
        if policy_checkpoint:
            from mbrl.policy import MbrlPolicy
            from mbrl.rate_models import TwinRateModel

            policy = MbrlPolicy(Path(policy_checkpoint))
            if not isinstance(policy.rate_model, TwinRateModel):
                raise ValueError(f"{policy_checkpoint}: a {policy.rate_model_name}-driven "
                                 "policy has no twin to start from")
            log.info(f"the twin of policy {policy_checkpoint} (version "
                     f"{policy.rate_model.twin.version})")
            return policy.rate_model.twin
        if self.weights is not None and self.weights.is_file():
            twin = UserDigitalTwin.load(self.weights)
            log.info(f"loaded twin version {twin.version} ({len(twin.states)} slots) from "
                     f"{self.weights}")
            return twin
        return UserDigitalTwin(config)

    def quantise(self, mbps: float) -> int:
        """Index of the state rate nearest to a measured throughput."""
        return int(np.argmin(np.abs(self.rates - mbps)))

    def _on_throughput(self, msg: Any) -> None:
        mbps = float(msg.achieved_mbps)
        if not math.isfinite(mbps) or mbps < 0 or mbps > self.max_mbps:
            self.rejected += 1
            self.node.get_logger().error(
                f"slot {msg.slot}: refused throughput {mbps!r} Mbit/s (must be finite, >= 0 and "
                f"<= max_mbps {self.max_mbps:g}); {self.refused} refused so far")
            return
        self.received += 1
        due = self.twin.observe(self.quantise(mbps))
        if due and self._training is None:
            data = self.twin.take_training_data()
            self._training = threading.Thread(target=self._retrain, args=(data,),
                                              name="udt-retrain", daemon=True)
            self._training.start()
        with self._lock:
            latent = self.twin.latent()
        out = new("twinslam_msgs/msg/RateLatent", slot=int(msg.slot),
                  model_version=latent.model_version,
                  mu=latent.mu.astype(np.float32), sigma=latent.sigma.astype(np.float32),
                  next_state_probs=latent.next_state_probs.astype(np.float32),
                  state_rates_mbps=self.rates.astype(np.float64))
        out.header.stamp = msg.header.stamp
        out.header.frame_id = msg.header.frame_id
        self.pub.publish(out)

    def _retrain(self, states: list[int]) -> None:
        """Runs on the training thread: train a copy, swap it in, save it."""
        log = self.node.get_logger()
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


def main(args: list[str] | None = None) -> int:
    # One intra-op thread: the retrain shares the machine with the spin thread (and on the
    # edge host with the other nodes), and the per-slot inference is tiny.
    torch.set_num_threads(1)
    node = node_runtime.start_node("udt_node", PARAMETERS, args)
    try:
        twin_node = TwinNode(node)
    except ValueError as exc:
        return node_runtime.fail(node, str(exc))
    node.get_logger().info(
        f"twin of {twin_node.rates.size} uplink states {twin_node.rates.tolist()} Mbit/s, "
        f"Z = {twin_node.twin.config.latent_dim}, retrain every "
        f"{twin_node.twin.config.retrain_every} slots; listening on {THROUGHPUT_TOPIC}")

    def stopping() -> None:
        twin_node.wait_for_training(30.0)
        node.get_logger().info(f"stopping: {twin_node.received} slots learned from, "
                               f"{twin_node.refused} refused")

    node_runtime.run(node, on_exit=stopping)
    return 0


if __name__ == "__main__":
    sys.exit(main())
