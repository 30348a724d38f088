"""Reading a ROS 2 parameter file as rcl gives its sections to a node: what the launchers need
to know of a node's parameters before it starts (a device's slot, a renamed node's section).
Only YAML: the ROS 2 launch file imports it in the ``ros2 launch`` process, where the live
launcher's imports (the fork servers, rclpy, the run's report) would cost ~1.8 s of start."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

#: rcl's key for every node of every namespace; ``/**/NAME`` is node NAME in any namespace
EVERY_NODE = "/**"


def any_namespace(node: str) -> str:
    """The parameter file key that gives a section to node ``node`` in any namespace: rcl
    gives a node only the sections keyed by its full name (``/ar1/device_tracker``), a
    wildcard that matches it, or — for a node in the root namespace alone — its plain name."""
    return f"{EVERY_NODE}/{node}"


def node_parameters(params_file: Path, node: str) -> dict[str, Any]:
    """The ``ros__parameters`` a ROS 2 parameter file gives ``node`` (by ``/**``, ``/**/NODE``,
    its plain name or ``/NODE``, the later overriding), for the launchers' own bookkeeping;
    the nodes read the file themselves."""
    doc = yaml.safe_load(Path(params_file).read_text(encoding="utf-8")) or {}
    out: dict[str, Any] = {}
    for key in (EVERY_NODE, any_namespace(node), node, f"/{node}"):
        out.update((doc.get(key) or {}).get("ros__parameters", {}))
    return out
