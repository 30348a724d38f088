"""The one place that knows every message type twinslam speaks.

The ``.msg`` files under ``msg_schemas/msg`` are the single source of truth for the custom
messages; the standard ROS 2 Jazzy definitions come from ``rosbags``' bundled type store.
Both are parsed into one :class:`rosbags.typesys.store.Typestore`, from which

* the Python message classes (typed dataclasses, numpy arrays for numeric arrays),
* our own CDR codec (:mod:`msg_schemas.cdr`),
* the Cyclone DDS topic types (:mod:`msg_schemas.dds_types`) and
* the RIHS01 type hashes that ROS 2 Jazzy puts in endpoint USER_DATA

are all derived, so a field added to a ``.msg`` file reaches every layer at once.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

#: ROS package name of the custom interfaces (``msg_schemas/package.xml`` builds it on ROS hosts).
INTERFACE_PACKAGE = "twinslam_msgs"
MSG_DIR = Path(__file__).resolve().parent / "msg"

#: numpy dtype of every ROS primitive that rosbags stores as a numpy array inside arrays/sequences.
PRIMITIVE_DTYPES: dict[str, str] = {
    "bool": "bool",
    "byte": "uint8",
    "char": "uint8",
    "int8": "int8",
    "uint8": "uint8",
    "int16": "int16",
    "uint16": "uint16",
    "int32": "int32",
    "uint32": "uint32",
    "int64": "int64",
    "uint64": "uint64",
    "float32": "float32",
    "float64": "float64",
}


def custom_message_names() -> list[str]:
    """Full names (``twinslam_msgs/msg/X``) of the custom messages, from the .msg files on disk."""
    return sorted(f"{INTERFACE_PACKAGE}/msg/{p.stem}" for p in MSG_DIR.glob("*.msg"))


@functools.lru_cache(maxsize=1)
def typestore() -> Typestore:
    """The ROS 2 Jazzy type store extended with twinslam's custom messages (built once)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name in custom_message_names():
        text = (MSG_DIR / f"{name.rsplit('/', 1)[1]}.msg").read_text(encoding="utf-8")
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def message_class(name: str) -> type:
    """The Python class of a message type, e.g. ``message_class('sensor_msgs/msg/Image')``."""
    store = typestore()
    try:
        return store.types[name]
    except KeyError:
        raise KeyError(f"unknown message type {name!r}: not a ROS 2 Jazzy type nor one of "
                       f"{custom_message_names()}") from None


def type_hash(name: str) -> str:
    """RIHS01 type hash of a message (REP 2016), as ROS 2 Jazzy advertises it in USER_DATA."""
    return typestore().hash_rihs01(name)


def _default_for(node: tuple[Any, Any]) -> Any:
    kind, detail = node
    kind = int(kind)
    if kind == 1:  # BASE
        base = detail[0]
        if base == "string":
            return ""
        if base == "bool":
            return False
        if base.startswith("float"):
            return 0.0
        return 0
    if kind == 2:  # NAME
        return new(detail)
    sub, length = detail
    sub_kind = int(sub[0])
    if sub_kind == 1 and sub[1][0] in PRIMITIVE_DTYPES:
        return np.zeros(length if kind == 3 else 0, dtype=PRIMITIVE_DTYPES[sub[1][0]])
    if kind == 3:  # ARRAY
        return [_default_for(sub) for _ in range(length)]
    return []  # SEQUENCE of strings or messages


def new(name: str, **fields: Any) -> Any:
    """A message of type ``name`` with ROS 2 default values for every field not given.

    rosbags' dataclasses have no defaults; rclpy messages do. Nodes use this so that code reads
    like rclpy's ``Image(height=480, ...)`` without spelling out every field.
    """
    cls = message_class(name)
    _consts, defs = typestore().fielddefs[name]
    known = {fname for fname, _ in defs}
    unknown = set(fields) - known
    if unknown:
        raise TypeError(f"{name} has no field(s) {sorted(unknown)}; fields are {sorted(known)}")
    values = {fname: fields[fname] if fname in fields else _default_for(node)
              for fname, node in defs}
    if name == "geometry_msgs/msg/Quaternion" and "w" not in fields:
        values["w"] = 1.0  # the .msg default (``float64 w 1``): an identity rotation
    return cls(**values)


def type_name_of(msg: Any) -> str:
    """The full ROS name of a message instance (``pkg/msg/Name``)."""
    name = getattr(msg, "__msgtype__", None)
    if name is None or not dataclasses.is_dataclass(msg):
        raise TypeError(f"{type(msg).__name__} is not a ROS message class of msg_schemas")
    return name
