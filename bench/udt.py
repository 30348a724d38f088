"""User digital twin benchmark: the variational twin's seconds per retrain on
W slots of data and milliseconds per slot of inference (μ, Σ and p(d_{k+1}) from the latest
history), beside the Bayesian regime twin's milliseconds per slot (filter update + latent), on
the same states in one run.

    python -m bench.udt [--states 2] [--retrains 5]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch

from bench.gauge import cpu_gauge
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin
from twinslam.twin.variational_twin import VariationalConfig, VariationalTwin
from twinslam.uplink.channels import MarkovChannel, random_transition_matrix, state_rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--states", type=int, default=2, help="N, uplink rate states")
    parser.add_argument("--retrains", type=int, default=5, help="retrains timed")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = VariationalConfig(n_states=args.states)
    matrix = random_transition_matrix(np.random.default_rng(0), args.states)
    channel = MarkovChannel(state_rates(args.states), matrix=matrix, seed=0)
    twin = VariationalTwin(config)
    print(f"machine: {platform.node()} {platform.machine()} python "
          f"{platform.python_version()}, torch {torch.__version__}, {args.threads} threads")
    print(cpu_gauge(), "(before)")
    retrain_s = []
    for _ in range(args.retrains):
        for _ in range(config.retrain_every):
            twin.observe(channel.step()[0])
        t0 = time.perf_counter()
        twin.retrain()
        retrain_s.append(time.perf_counter() - t0)
    infer_ms = []
    for _ in range(200):
        twin.observe(channel.step()[0])
        t0 = time.perf_counter()
        twin.latent()
        infer_ms.append((time.perf_counter() - t0) * 1000)
    print(f"retrain (W = {config.retrain_every} slots, buffer {config.buffer_slots}, "
          f"{config.steps_per_retrain} Adam steps of {config.batch_size} windows of "
          f"{config.history} slots): median {np.median(retrain_s):.2f} s "
          f"(min {min(retrain_s):.2f}, max {max(retrain_s):.2f})")
    print(f"inference per slot: median {np.median(infer_ms):.2f} ms, "
          f"p99 {np.percentile(infer_ms, 99):.2f} ms")
    regime = RegimeTwin(RegimeConfig(n_states=args.states))
    for s in twin.states:                       # the same history, so the filter is warm
        regime.observe(s)
    step_ms = []
    for _ in range(2000):
        state = channel.step()[0]
        t0 = time.perf_counter()
        regime.observe(state)
        regime.latent()
        step_ms.append((time.perf_counter() - t0) * 1000)
    print(f"regime twin, update + latent per slot ({len(regime.config.hazards)} hazards, "
          f"<= {regime.config.max_hypotheses} hypotheses each): median "
          f"{np.median(step_ms):.2f} ms, p99 {np.percentile(step_ms, 99):.2f} ms")
    print(cpu_gauge(), "(after)")


if __name__ == "__main__":
    main()
