"""Model-based RL map management (the paper's AMM, §VI and Algorithm 2; docs/architecture.md §3).

An actor-critic learns which frames to upload and which to evict from the map graph and the
slot's candidate frames, augmented with the uplink's rate history and a rate model's latent
features; its replay batches blend real slots with artificial ones a rate model generates.
The pure core (state, networks, replay, rate models, trainer) needs no DDS; the edge node runs
a trained actor through :class:`twinslam.mbrl.policy.MbrlPolicy` like any other policy.
"""
