"""Every map-management policy, in one package (docs/architecture.md §13).

What a policy sees and answers (``actions.py``), the one :class:`MapPolicy` protocol with its
optional capabilities (``protocol.py``), the paper's rules and the random control
(``rules.py``), restoring from the edge's archive (``restoring.py``), decisions handed back
late (``delayed.py``), the world model a planner imagines the future in and the simulator
steps (``world_model.py``), whole-episode plans (``plan.py``), the causal planner
(``mpc.py``), the clairvoyant reference (``reference.py``), the exact optimum on small
instances (``exact_optimum.py``), the learned actor (``learned/``, the only part that loads
torch) and every policy by name (``registry.py``).
"""
