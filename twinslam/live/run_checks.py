"""What a live run's options must satisfy before any node starts: ``twinslam launch`` and
``twinslam evaluate`` refuse a bad parameter file or an unknown policy with the reason, instead
of starting the player and the device and learning it from a traceback or the edge's exit."""

from __future__ import annotations

from pathlib import Path

import yaml

from edge_mapper.policy_control import policy_refused


def params_file_problem(path: Path) -> str | None:
    """Why ``path`` is not a ROS 2 parameter file the nodes can read (None: it is one): it must
    exist, parse as YAML and map node names to ``{ros__parameters: {name: value}}``."""
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
