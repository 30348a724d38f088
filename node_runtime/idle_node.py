"""A node whose real work has not landed yet: it joins the graph, says so, and does nothing.

Used by the node entry points until their issue fills them in. It declares the node's documented
parameters so that parameter files are already checked, and it never publishes: nothing pretends
to work.
"""

from __future__ import annotations

from typing import Any

import node_runtime


def run_idle_node(name: str, parameters: dict[str, Any], pending: str,
                  args: list[str] | None = None) -> int:
    """Start, log what is missing, spin until SIGINT/SIGTERM, exit 0."""
    node_runtime.init(args=args)
    node = node_runtime.Node(name)
    for key, default in parameters.items():
        node.declare_parameter(key, default)
    node.get_logger().warning(f"{pending}: this node joins the graph but publishes nothing yet")
    node_runtime.run(node)
    return 0
