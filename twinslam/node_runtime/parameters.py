"""Node parameters declared the ROS 2 way: a type, a range, a description, and whether the
value may change while the node runs.

A node lists its parameters as :class:`ParamSpec` s and calls :func:`declare`: each becomes an
rclpy parameter with a ``ParameterDescriptor`` (so ``ros2 param describe`` explains it), an
integer or floating-point range where one applies (rclpy refuses a value outside it, at start-up
from ``-p``/``--params-file`` and at run time from ``ros2 param set``), ``read_only`` unless the
node applies changes live, and an optional check of its own (a policy name that must exist, a
channel spec that must parse) that runs on every set with the reason returned to the caller.
"""

from __future__ import annotations

import difflib
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from twinslam.node_runtime.node_main import NodeStartError
from twinslam.node_runtime.parameter_files import params_files, unreached_sections

#: a check of one value: None when fine, else the reason it is refused
Check = Callable[[Any], "str | None"]

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
          tuple: ParameterType.PARAMETER_STRING_ARRAY}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: default (whose type is the parameter's), description, range, liveness."""

    name: str
    default: bool | int | float | str | tuple[str, ...]    #: a tuple: a string array
    description: str
    low: float | None = None          #: inclusive bounds of an int or float parameter
    high: float | None = None
    live: bool = False                #: applied while running; otherwise read-only
    check: Check | None = None        #: further validation (also for live changes)

    def descriptor(self) -> ParameterDescriptor:
        kind = type(self.default)
        desc = ParameterDescriptor(name=self.name, type=_TYPES[kind],
                                   description=self.description, read_only=not self.live)
        if kind is int and (self.low is not None or self.high is not None):
            desc.integer_range = [IntegerRange(
                from_value=int(self.low if self.low is not None else -(2 ** 63)),
                to_value=int(self.high if self.high is not None else 2 ** 63 - 1), step=0)]
        elif kind is float and (self.low is not None or self.high is not None):
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(self.low if self.low is not None else -sys.float_info.max),
                to_value=float(self.high if self.high is not None else sys.float_info.max),
                step=0.0)]
        if not self.live:
            desc.additional_constraints = "read-only: set it at start (-p, --params-file)"
        return desc


class ParameterStartError(NodeStartError):
    """A parameter value given at start-up that the node refuses; the message says why."""


def declare(node: Node, specs: Sequence[ParamSpec], argv: Sequence[str] | None = None
            ) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` (overrides from the command line and parameter files
    apply) and return their values by name. Raises :class:`ParameterStartError` with the
    parameter and the reason when a given value is refused. Warns of values given that the
    node has no parameter for, and of parameter files among ``argv``'s ROS arguments (the
    process's, by default) whose sections for the node cannot reach it."""
    checks = {s.name: s.check for s in specs if s.check is not None}

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for param in params:
            check = checks.get(param.name)
            reason = check(param.value) if check is not None else None
            if reason:
                return SetParametersResult(successful=False,
                                           reason=f"{param.name} := {param.value!r}: {reason}")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    values = {}
    for spec in specs:
        # an empty array has no type of its own: rclpy takes the descriptor's (value unset)
        default: Any = (list(spec.default) or Parameter.Type.STRING_ARRAY
                         if isinstance(spec.default, tuple) else spec.default)
        try:
            value = node.declare_parameter(spec.name, default, spec.descriptor()).value
            values[spec.name] = (list(value or []) if isinstance(spec.default, tuple)
                                 else value)
        except InvalidParameterTypeException as exc:
            raise ParameterStartError(
                f"parameter {spec.name} takes a {type(spec.default).__name__} "
                f"({spec.description}): {exc}{_decimal_hint(spec, exc)}") from None
        except (InvalidParameterValueException, ParameterException) as exc:
            raise ParameterStartError(f"parameter {spec.name}: {exc}") from None
    _warn_unread(node, [s.name for s in specs])
    _warn_unreached(node, sys.argv if argv is None else argv)
    return values


#: parameters rclpy declares on every node itself, and the prefix of those its publishers and
#: subscriptions declare when created with QoS overrides
RCLPY_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
QOS_OVERRIDES = "qos_overrides."


def rclpy_own(name: str) -> bool:
    """Whether rclpy, not the node's code, declares parameter ``name``."""
    return name in RCLPY_PARAMETERS or name.startswith(QOS_OVERRIDES)


def likely_name(name: str, known: Sequence[str]) -> str:
    """`` (did you mean NAME?)`` naming the parameter of ``known`` closest to a misspelt
    ``name`` (difflib's), or "" where none is close."""
    close = difflib.get_close_matches(name, sorted(known), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


def _warn_unread(node: Node, declared: Sequence[str]) -> None:
    """Warn of each value given the node (``-p``, ``--params-file``) that it never reads: a
    misspelt name would otherwise leave the node on the default without a word. A warning,
    not a refusal: a file shared with other nodes may hold what only they read."""
    given = getattr(node, "_parameter_overrides", {})       # rclpy's, from the arguments
    for name in sorted(set(given) - set(declared)):
        if not rclpy_own(name):
            node.get_logger().warning(
                f"parameter {name} is given but {node.get_name()} has no such parameter"
                f"{likely_name(name, declared)}: ignored")


def _warn_unreached(node: Node, argv: Sequence[str]) -> None:
    """Warn of each parameter file section that names the node but not its namespace (most
    often a plain name, which only the root namespace's node reads) when no section of that
    file reaches it: the node runs on its defaults whatever the section says."""
    name, namespace = node.get_name(), node.get_namespace()
    fqn = f"{namespace.rstrip('/')}/{name}"
    for section in unreached_sections(params_files(argv), name, namespace):
        node.get_logger().warning(
            f"parameter file section {section} does not reach {fqn} (rcl gives a section to "
            f"the nodes its key names, a plain name to the root namespace's node only); key "
            f"it /**/{name} (any namespace) or {fqn}. Running on the defaults")


def _decimal_hint(spec: ParamSpec, exc: Exception) -> str:
    """For a float parameter given a whole number (``-p slot_timeout_s:=60``): ROS reads it
    as an integer and refuses it, the most common way to meet this error; say what to write."""
    given = re.search(r"to '(-?\d+)' of type 'INTEGER'", str(exc))
    if isinstance(spec.default, float) and given:
        return f" (ROS reads {given[1]} as an integer: write {spec.name}:={given[1]}.0)"
    return ""
