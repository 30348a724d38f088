"""Parsing of ROS 2 command-line arguments (``--ros-args ... [--]``).

Supported, as ``ros2 run`` users type them: ``-r/--remap [node:]from:=to`` (including
``__node:=`` and ``__ns:=``), ``-p/--param [node:]name:=value`` (value parsed as YAML, as rcl
does), ``--params-file FILE`` (ROS 2 YAML format) and ``--log-level LEVEL``.
Unknown ROS arguments are an error, not a silent no-op.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from node_runtime.names import RemapRule


class ArgumentError(ValueError):
    """A malformed ``--ros-args`` section."""


@dataclass
class RosArguments:
    """Everything ``--ros-args`` said, in command-line order where order matters."""

    remaps: list[RemapRule] = field(default_factory=list)
    #: (node or None, parameter name, value) from ``-p``; later entries win
    params: list[tuple[str | None, str, Any]] = field(default_factory=list)
    params_files: list[Path] = field(default_factory=list)
    log_level: str | None = None

    def special(self, key: str, node_name: str) -> str | None:
        """Value of ``__node`` / ``__ns`` for this node, the last matching rule winning."""
        value = None
        for rule in self.remaps:
            if rule.source == key and rule.applies_to(node_name):
                value = rule.target
        return value


def parse_param(text: str) -> tuple[str | None, str, Any]:
    if ":=" not in text:
        raise ArgumentError(f"parameter {text!r} lacks ':=' (use -p name:=value)")
    lhs, raw = text.split(":=", 1)
    node = None
    if ":" in lhs:
        node, lhs = lhs.split(":", 1)
    if not lhs:
        raise ArgumentError(f"parameter {text!r} has no name")
    try:
        value = yaml.safe_load(raw) if raw != "" else ""
    except yaml.YAMLError as exc:
        raise ArgumentError(f"parameter {text!r}: value is not valid YAML: {exc}") from None
    return node, lhs, value


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """Split ``argv`` into (user arguments, ROS arguments), as rclpy.utilities does."""
    user: list[str] = []
    ros: list[str] = []
    in_ros = False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
        elif in_ros:
            ros.append(arg)
        else:
            user.append(arg)
    return user, ros


def parse_ros_args(argv: list[str]) -> RosArguments:
    """Parse the ROS part of a command line (``argv`` may contain user arguments too)."""
    _user, ros = split_ros_args(argv)
    out = RosArguments()
    it = iter(ros)
    for arg in it:
        if arg in ("-r", "--remap", "-p", "--param", "--params-file", "--log-level"):
            try:
                value = next(it)
            except StopIteration:
                raise ArgumentError(f"{arg} needs a value") from None
            if arg in ("-r", "--remap"):
                try:
                    out.remaps.append(RemapRule.parse(value))
                except ValueError as exc:
                    raise ArgumentError(str(exc)) from None
            elif arg in ("-p", "--param"):
                out.params.append(parse_param(value))
            elif arg == "--params-file":
                path = Path(value)
                if not path.is_file():
                    raise ArgumentError(f"--params-file {value}: no such file")
                out.params_files.append(path)
            else:
                out.log_level = value.split(":=")[-1].lower()
        else:
            raise ArgumentError(f"unknown ROS argument {arg!r} (supported: -r, -p, "
                                "--params-file, --log-level)")
    return out
