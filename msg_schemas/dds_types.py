"""Cyclone DDS topic types for ROS 2 messages, built from the same field definitions.

Cyclone needs a type to create a topic: it gives the topic its DDS type name
(``pkg::msg::dds_::Name_``, the ROS 2 convention), its XTypes type object, and the description
Cyclone uses to check every serialised sample we write. Building that type from the .msg-derived
field definitions keeps the ``.msg`` files the single source of truth; a wrong mapping shows up at
once as a refused write.

Samples themselves never go through Cyclone's Python serialiser: the node runtime writes the bytes
of :mod:`msg_schemas.cdr` directly.
"""

from __future__ import annotations

import functools
from typing import Any

from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as t

from msg_schemas.registry import typestore

_PRIMITIVES: dict[str, Any] = {
    "bool": bool,
    "byte": t.byte,
    "char": t.uint8,  # ROS 2 maps msg 'char' to IDL uint8
    "int8": t.int8,
    "uint8": t.uint8,
    "int16": t.int16,
    "uint16": t.uint16,
    "int32": t.int32,
    "uint32": t.uint32,
    "int64": t.int64,
    "uint64": t.uint64,
    "float32": t.float32,
    "float64": t.float64,
}


def dds_type_name(ros_name: str) -> str:
    """``sensor_msgs/msg/Image`` → ``sensor_msgs::msg::dds_::Image_`` (rmw_cyclonedds' naming)."""
    pkg, kind, name = ros_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def _annotation(node: tuple[Any, Any]) -> Any:
    kind, detail = int(node[0]), node[1]
    if kind == 1:
        base, bound = detail
        if base == "string":
            return t.bounded_str[bound] if bound else str
        return _PRIMITIVES[base]
    if kind == 2:
        return dds_type(detail)
    sub, count = detail
    if kind == 3:
        return t.array[_annotation(sub), count]
    return t.sequence[_annotation(sub), count] if count else t.sequence[_annotation(sub)]


@functools.cache
def dds_type(ros_name: str) -> type[IdlStruct]:
    """The Cyclone IdlStruct class of a ROS message type (cached; nested types reused)."""
    _consts, defs = typestore().fielddefs[ros_name]
    fields = {fname: _annotation(node) for fname, node in defs}
    if not fields:
        fields = {"structure_needs_at_least_one_member": t.uint8}
    return make_idl_struct(ros_name.rsplit("/", 1)[1] + "_", dds_type_name(ros_name), fields)
