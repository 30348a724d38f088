"""The twin node's ROS parameters: name, default, description and range (``ros2 param
describe /udt_node states`` shows them; a value out of range stops the node with the reason)."""

from __future__ import annotations

from twinslam.node_runtime.parameters import ParamSpec
from twinslam.slot_protocol import table1
from twinslam.twin.registry import ALIASES, TWIN_MODELS

#: what ``model`` accepts: the twins, and ``udt`` (the variational twin's old name)
MODELS = (*TWIN_MODELS, *ALIASES)

PARAMETERS = (
    ParamSpec("model", "regime", "regime (Bayesian regime twin) or variational (the paper's "
              "variational twin; udt: its old name)",
              check=lambda v: None if v in MODELS else f"must be one of {', '.join(MODELS)}"),
    ParamSpec("states", 2, "N uplink states, spread over [rate_min, rate_max]", low=1, high=64),
    ParamSpec("latent_dim", 8, "variational: Z, the latent's dimensions", low=1, high=1024),
    ParamSpec("history", 8, "variational: tau + 1 slots of rate history the encoder reads",
              low=1, high=10_000),
    ParamSpec("retrain_every", 100, "variational: W, slots between retrains (background "
              "thread)", low=1, high=1_000_000),
    ParamSpec("buffer_slots", 600, "variational: real experiences a retrain learns from", low=1,
              high=10_000_000),
    ParamSpec("steps_per_retrain", 100, "variational: optimiser steps per retrain", low=1,
              high=1_000_000),
    ParamSpec("rate_min", table1.RATE_MIN_MBPS, "Mbit/s of the lowest state", low=0.0, high=1e6),
    ParamSpec("rate_max", table1.RATE_MAX_MBPS, "Mbit/s of the highest state", low=0.0, high=1e6),
    ParamSpec("max_mbps", 10_000.0, "a larger throughput report is refused as absurd",
              low=0.0, high=1e9),
    ParamSpec("weights", "", "variational: file to load at start and save after each retrain"),
    ParamSpec("seed", 0, "variational: seed of the twin's training", low=0),
    ParamSpec("policy_checkpoint", "", "run the twin of this AMM policy (rate model regime or "
              "variational) instead of model"),
)
