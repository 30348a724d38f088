"""Node parameters and ROS 2 YAML parameter files.

A parameter file maps node names (``/**``, ``talker``, ``/ns/talker``, with ``*`` and ``**``
wildcards, or nested namespace mappings) to a ``ros__parameters`` mapping, exactly the files
``ros2 run ... --ros-args --params-file`` reads. Nested dictionaries become dotted names
(``a: {b: 1}`` → ``a.b``), as in rclpy.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml


class ParameterError(ValueError):
    """A parameter that was not declared, or a malformed parameter file."""


@dataclass(frozen=True)
class Parameter:
    """A named value, shaped like rclpy's ``Parameter`` (``.name``, ``.value``)."""

    name: str
    value: Any


def _pattern_to_regex(pattern: str) -> re.Pattern[str]:
    if not pattern.startswith("/"):
        pattern = "/" + pattern
    out = ""
    i = 0
    while i < len(pattern):
        if pattern.startswith("**", i):
            out += ".*"
            i += 2
        elif pattern[i] == "*":
            out += "[^/]*"
            i += 1
        else:
            out += re.escape(pattern[i])
            i += 1
    return re.compile(out + "$")


def _flatten(prefix: str, mapping: dict[str, Any], out: dict[str, Any]) -> None:
    for key, value in mapping.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict):
            _flatten(name, value, out)
        else:
            out[name] = value


def _collect(prefix: str, doc: dict[str, Any], fq_node: str, out: dict[str, Any],
             path: Path) -> None:
    for key, value in doc.items():
        if not isinstance(value, dict):
            raise ParameterError(f"{path}: entry {prefix}/{key} is not a mapping")
        name = f"{prefix}/{key.strip('/')}" if prefix else str(key)
        if "ros__parameters" in value:
            if _pattern_to_regex(name).match(fq_node):
                params = value["ros__parameters"]
                if not isinstance(params, dict):
                    raise ParameterError(f"{path}: {name}.ros__parameters is not a mapping")
                _flatten("", params, out)
        else:
            _collect(name, value, fq_node, out, path)


def load_params_file(path: Path, fq_node: str) -> dict[str, Any]:
    """The parameters that ``path`` gives the node with fully qualified name ``fq_node``."""
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParameterError(f"parameter file {path} does not exist") from None
    except yaml.YAMLError as exc:
        raise ParameterError(f"parameter file {path} is not valid YAML: {exc}") from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ParameterError(f"parameter file {path}: top level must map node names")
    out: dict[str, Any] = {}
    _collect("", doc, fq_node, out, path)
    return out
