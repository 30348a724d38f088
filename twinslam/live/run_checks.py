"""What a live run's options must satisfy before any node starts: ``twinslam launch`` and
``twinslam evaluate`` refuse a bad parameter file or an unknown policy with the reason, instead
of starting the player and the device and learning it from a traceback or the edge's exit."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import yaml

from device_tracker.parameters import PARAMETERS as DEVICE
from edge_mapper.parameters import PARAMETERS as EDGE
from edge_mapper.policy_control import policy_refused
from twinslam.node_runtime.parameters import ParamSpec, likely_name, rclpy_own
from twinslam.sequence_player.parameters import PARAMETERS as PLAYER
from udt_node.parameters import PARAMETERS as TWIN

#: every twinslam node's parameters by node name
NODE_PARAMETERS: dict[str, Sequence[ParamSpec]] = {
    "sequence_player": PLAYER, "device_tracker": DEVICE, "edge_mapper": EDGE, "udt_node": TWIN}


def params_file_problem(path: Path) -> str | None:
    """Why ``path`` is not a ROS 2 parameter file the nodes can read (None: it is one): it must
    exist, parse as YAML and map node names to ``{ros__parameters: {name: value}}``, and a
    section for a twinslam node may name only parameters that node has
    (:func:`unknown_parameter`)."""
    if not path.is_file():
        return f"parameter file {path} does not exist"
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        return f"parameter file {path} is not YAML: {exc}"
    if doc is None:
        return None                                  # empty: every node on its defaults
    if not isinstance(doc, dict):
        return (f"parameter file {path} is not a parameter mapping (NODE: {{ros__parameters: "
                f"{{NAME: VALUE}}}}): its top level is a {type(doc).__name__}")
    for node, body in doc.items():
        params = body.get("ros__parameters") if isinstance(body, dict) else None
        if not isinstance(params, dict):
            return (f"parameter file {path}: {node!r} must hold a ros__parameters mapping "
                    "(NODE: {ros__parameters: {NAME: VALUE}})")
        unknown = unknown_parameter(str(node), params)
        if unknown:
            return f"parameter file {path}: {unknown}"
    return None


def unknown_parameter(key: str, params: dict[str, object]) -> str | None:
    """Why a section keyed ``key`` names a parameter its twinslam node does not have (a
    typo a node would ignore, starting on the default instead), or None. A section of
    another node, or of every node (``/**``), is not checked: it may be meant for others."""
    node = key.rsplit("/", 1)[-1]
    specs = NODE_PARAMETERS.get(node)
    if specs is None or key == "/**":
        return None
    known = [s.name for s in specs]
    for name in map(str, params):
        if name not in known and not rclpy_own(name):
            return (f"{node} has no parameter {name!r}{likely_name(name, known)}: a node "
                    "leaves what it does not declare unread; docs/parameters.md lists what "
                    "each node reads")
    return None


def policy_problem(spec: str) -> str | None:
    """Why the edge could not run the policy ``spec`` (None: it can); a learned policy's
    checkpoint must exist (it is loaded by the run, not here)."""
    kind, _, path = spec.partition(":")
    if kind == "mbrl":
        if not path:
            return "a learned policy names its checkpoint: mbrl:CHECKPOINT (`twinslam train`)"
        return None if Path(path).is_file() else (
            f"{path}: no such policy checkpoint (`twinslam train`)")
    reason = policy_refused(spec)
    return None if reason is None else f"policy {spec!r}: {reason}"
