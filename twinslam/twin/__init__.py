"""The user digital twin and its baselines as a library (paper §V).

The twin node (``udt_node``), the learner's rate models and the twin experiments all use it,
so it sits below each of them. ``latent`` is numpy-only: the edge reads the twin's features
without importing torch.
"""
