"""The generated ROS 2 message classes, reached by type name and filled from numpy arrays.

``twinslam_msgs`` (built by rosidl from ``msg_schemas/msg``) and ROS 2 Jazzy's standard
interfaces are ordinary Python packages of rosidl-generated classes. The project's conversions
work in numpy; rosidl stores a primitive sequence as an ``array.array`` and checks nothing by
default (``ROS_PYTHON_CHECK_FIELDS`` unset), so a numpy array handed to it element by element
costs a Python call per element. :func:`new` builds a message with every primitive sequence
converted in one buffer copy, which is what keeps a 921 600-byte image or a map of thousands of
points cheap.
"""

from __future__ import annotations

import array
import functools
import importlib
from pathlib import Path
from typing import Any, TypeVar, overload

import numpy as np

#: a generated message class
M = TypeVar("M")
#: ROS package name of the custom interfaces (``msg_schemas/package.xml``)
INTERFACE_PACKAGE = "twinslam_msgs"

#: rosidl's name of a primitive → (numpy dtype, array.array type code) of its sequences
SEQUENCE_CODES: dict[str, tuple[str, str]] = {
    "boolean": ("bool", ""),
    "octet": ("uint8", ""),
    "uint8": ("uint8", "B"),
    "int8": ("int8", "b"),
    "uint16": ("uint16", "H"),
    "int16": ("int16", "h"),
    "uint32": ("uint32", "I"),
    "int32": ("int32", "i"),
    "uint64": ("uint64", "Q"),
    "int64": ("int64", "q"),
    "float": ("float32", "f"),
    "double": ("float64", "d"),
}


class UnknownMessageType(LookupError):
    """A type name that names no installed interface package's message."""


@functools.cache
def message_class(type_name: str) -> type:
    """The generated class of ``pkg/msg/Name`` (``sensor_msgs/msg/Image``)."""
    try:
        package, kind, name = type_name.split("/")
        if kind != "msg":
            raise ValueError
    except ValueError:
        raise UnknownMessageType(f"{type_name!r} is not a message type name of the form "
                                 "pkg/msg/Name") from None
    try:
        cls: type = getattr(importlib.import_module(f"{package}.msg"), name)
        return cls
    except (ImportError, AttributeError):
        hint = (" (run `make` to build the interface package)" if package == INTERFACE_PACKAGE
                else "")
        raise UnknownMessageType(f"no message type {type_name}{hint}") from None


def type_name_of(msg: Any) -> str:
    """``pkg/msg/Name`` of a generated message or message class."""
    cls = msg if isinstance(msg, type) else type(msg)
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


@functools.cache
def _sequence_codes(cls: Any) -> dict[str, tuple[str, str]]:
    """Field → (dtype, type code) for the primitive sequences of ``cls``."""
    out = {}
    for name, kind in cls.get_fields_and_field_types().items():
        if kind.startswith("sequence<") and kind[9:-1] in SEQUENCE_CODES:
            out[name] = SEQUENCE_CODES[kind[9:-1]]
    return out


def as_sequence(values: Any, dtype: str, code: str) -> Any:
    """``values`` as rosidl stores a primitive sequence: an ``array.array`` filled from one
    buffer (numpy arrays, bytes, lists alike)."""
    if not code:
        return list(values)
    if isinstance(values, array.array) and values.typecode == code:
        return values
    # filled from the numpy buffer itself: through ``tobytes()`` first (a second copy) a
    # 640×480 rgb8 image took 0.6 ms, filled once 0.06 ms
    out = array.array(code)
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).reshape(-1).data.cast("B"))
    return out


@overload
def new(type_name: type[M], **fields: Any) -> M: ...


@overload
def new(type_name: str, **fields: Any) -> Any: ...


def new(type_name: str | type[Any], **fields: Any) -> Any:
    """A message of ``type_name`` (or class: then typed as that class) with ``fields`` set;
    primitive sequences may be given as numpy arrays, fixed-size arrays as anything numpy
    takes."""
    cls = message_class(type_name) if isinstance(type_name, str) else type_name
    codes = _sequence_codes(cls)
    # set one by one on an empty message: rosidl's constructor copies a sequence twice and
    # took 0.6 ms for a 640×480 rgb8 image where the setter takes 0.06; a name the type does
    # not have is an AttributeError here (the constructor ignored it without field checks)
    msg = cls()
    for name, value in fields.items():
        setattr(msg, name, as_sequence(value, *codes[name]) if name in codes else value)
    return msg


def custom_message_names() -> list[str]:
    """``twinslam_msgs/msg/X`` of every .msg file the package is built from."""
    msg_dir = Path(__file__).resolve().parent / "msg"
    return sorted(f"{INTERFACE_PACKAGE}/msg/{p.stem}" for p in msg_dir.glob("*.msg"))
