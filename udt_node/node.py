"""udt_node: the user digital twin as a ROS 2 node (paper §V, Algorithm 1).

Subscribes ``device/uplink_throughput`` (``twinslam_msgs/UplinkThroughput``, one per slot),
quantises the achieved throughput to the nearest of N rates spread over [``rate_min``,
``rate_max``] and publishes ``udt/rate_latent`` (``RateLatent``: μ, Σ, p(d_{k+1}), model
version) for every slot, from one of two twins (``model``):

* ``regime`` (default): the Bayesian regime twin (:mod:`twinslam.twin.regime_twin`), a filter
  updated every slot — μ, Σ are the mean and variance of the current regime's N×N matrix, the
  version counts the slots it has seen. It predicts the next state best of the models measured
  (docs/results/twin.md).
* ``variational``: the paper's variational twin. It keeps the real-experience buffer; every
  ``retrain_every`` slots it is retrained on a background thread, warm-started; callbacks never
  wait for it, and the trained network is swapped in when ready (the executor's callbacks and
  the training thread share only the swap, under a lock). With ``weights`` set, it is loaded
  from that file at start (if present) and saved after every retrain.

With ``policy_checkpoint`` set to a twin-driven AMM policy (``twinslam train --rate-model
regime|variational``), the node runs that policy's twin — its model and its configuration (the
variational twin: its weights) — so the latents the edge feeds it mean what they meant in
training; ``model`` is then not consulted.

A throughput that is NaN, infinite or negative (refused by the message validation of
:mod:`msg_schemas.validation`) or above ``max_mbps`` (refused here) is logged as an error,
counted, and left out of the buffer.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any, NoReturn

import torch
from rclpy.node import Node
from twinslam_msgs.msg import RateLatent, UplinkThroughput

from msg_schemas import qos, topics
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.matched_readers import logging_matches
from twinslam.node_runtime.node_main import NodeStartError, exit_process, run_node
from twinslam.node_runtime.parameters import declare
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin
from twinslam.twin.registry import canonical
from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin
from twinslam.uplink.quantiser import RateQuantiser
from udt_node.messages import rate_latent_message
from udt_node.parameters import PARAMETERS

#: the twins the node runs (both satisfy twinslam.twin.rate_model.Twin)
RunnableTwin = RegimeTwin | VariationalTwin


class TwinNode(Node):
    """Topic ↔ twin wiring; the learning lives in the twin (:mod:`twinslam.twin`)."""

    def __init__(self) -> None:
        super().__init__("udt_node")
        p = declare(self, PARAMETERS)
        #: a measured rate's state: the nearest of N rates spread over [rate_min, rate_max]
        self.quantiser = RateQuantiser.evenly(int(p["states"]), float(p["rate_min"]),
                                              float(p["rate_max"]))
        self.rates = self.quantiser.rates
        self.max_mbps = float(p["max_mbps"])
        self.weights = Path(p["weights"]) if p["weights"] else None
        try:
            self.twin = self._load_or_create(p)
        except (ValueError, OSError) as exc:
            raise NodeStartError(str(exc)) from None
        if self.twin.n_states != int(p["states"]):
            raise NodeStartError(f"a {self.twin.n_states}-state twin, states:={p['states']} "
                                 "asked for")
        self.rejected = 0
        self.received = 0
        self._lock = threading.Lock()            # guards the twin's network swap
        self._training: threading.Thread | None = None
        self.pub = self.create_publisher(RateLatent, topics.RATE_LATENT, qos.PROTOCOL,
                                         event_callbacks=logging_matches(self, topics.RATE_LATENT))
        self.sub = CheckedSubscription(self, UplinkThroughput, topics.UPLINK_THROUGHPUT,
                                       self._on_throughput, qos.PROTOCOL)

    def _load_or_create(self, p: dict[str, Any]) -> RunnableTwin:
        log = self.get_logger()
        if p["policy_checkpoint"]:
            return self._policy_twin(str(p["policy_checkpoint"]))
        n = int(p["states"])
        if canonical(str(p["model"])) == "regime":
            if self.weights is not None:
                log.warning("weights is for model:=variational; the regime twin has none "
                            "(ignored)")
            return RegimeTwin(RegimeConfig(n_states=n))
        if p["model"] != "variational":
            log.warning(f"model:={p['model']} is the old name of model:=variational")
        if self.weights is not None and self.weights.is_file():
            twin = VariationalTwin.load(self.weights)
            log.info(f"loaded twin version {twin.version} ({len(twin.states)} slots) from "
                     f"{self.weights}")
            return twin
        return VariationalTwin(VariationalConfig(
            n_states=n, latent_dim=int(p["latent_dim"]), history=int(p["history"]),
            retrain_every=int(p["retrain_every"]), buffer_slots=int(p["buffer_slots"]),
            steps_per_retrain=int(p["steps_per_retrain"]), seed=int(p["seed"])))

    def _policy_twin(self, checkpoint: str) -> RunnableTwin:
        """The twin a twin-driven policy was trained with, as it starts a run."""
        # imported here: only a node given a policy checkpoint needs the learning layer
        from twinslam.policies.learned.policy import MbrlPolicy

        model = MbrlPolicy(Path(checkpoint)).rate_model
        if not isinstance(model, RunnableTwin):        # the registry's TWIN_MODELS
            raise ValueError(f"{checkpoint}: a {model.name}-driven policy has no twin to start "
                             "from")
        model.reset()                           # a filter starts the run from its prior
        self.get_logger().info(f"the {model.describe()} of policy {checkpoint}")
        return model

    def _on_throughput(self, msg: UplinkThroughput) -> None:
        mbps = float(msg.achieved_mbps)
        if not math.isfinite(mbps) or mbps < 0 or mbps > self.max_mbps:
            self.rejected += 1
            self.get_logger().error(
                f"slot {msg.slot}: refused throughput {mbps!r} Mbit/s (must be finite, >= 0 and "
                f"<= max_mbps {self.max_mbps:g}); {self.refused} refused so far")
            return
        self.received += 1
        due = self.twin.observe(self.quantiser.state(mbps))
        if due and self._training is None and isinstance(self.twin, VariationalTwin):
            data = self.twin.take_training_data()
            self._training = threading.Thread(target=self._retrain, args=(self.twin, data),
                                              name="udt-retrain", daemon=True)
            self._training.start()
        with self._lock:
            latent = self.twin.latent()
        self.pub.publish(rate_latent_message(int(msg.slot), latent, self.rates,
                                             msg.header.stamp, msg.header.frame_id))

    def _retrain(self, twin: VariationalTwin, states: list[int]) -> None:
        """Runs on the training thread: train a copy, swap it in, save it."""
        log = self.get_logger()
        try:
            network, trace = twin.train_copy(states)
            with self._lock:
                twin.adopt(network, trace)
                if self.weights is not None:
                    twin.save(self.weights)
            if trace:
                log.info(f"retrained on {len(states)} slots: model version "
                         f"{twin.version}, negative ELBO {trace[0]:.3f} -> {trace[-1]:.3f}")
        except Exception as exc:  # a failed retrain must not kill the node
            log.error(f"retrain failed, keeping model version {twin.version}: {exc}")
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


def main(args: list[str] | None = None) -> NoReturn:
    # One intra-op thread: the retrain shares the machine with the spin thread (and on the
    # edge host with the other nodes), and the per-slot inference is tiny.
    torch.set_num_threads(1)

    def started(twin_node: TwinNode) -> None:
        twin_node.get_logger().info(
            f"{twin_node.twin.describe()} of {twin_node.rates.size} uplink states "
            f"{twin_node.rates.tolist()} Mbit/s; listening on {twin_node.sub.topic_name}")

    exit_process(run_node("udt_node", TwinNode, args, started=started))


if __name__ == "__main__":
    main()
