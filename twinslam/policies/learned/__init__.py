"""The learned map-management policy (the paper's AMM, §VI; docs/architecture.md §3).

An actor-critic that scores the map graph and the slot's candidate frames, augmented with
the uplink's rate history and a rate model's latent features (``state.py``, ``networks.py``),
its replay buffer (``replay.py``) and the adapter that runs a trained checkpoint as a policy
(``policy.py``: :class:`MbrlPolicy`). Training it is :mod:`twinslam.training`.
"""
