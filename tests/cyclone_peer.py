"""An independent DDS implementation as the nodes' outside peer: Eclipse Cyclone DDS (PyPI
``cyclonedds``), which is not rclpy, not Fast DDS and shares no code with either.

* :func:`idl_type` builds Cyclone's type for a ROS message class from the class's rosidl
  definition, with ROS 2's DDS names (``sensor_msgs::msg::dds_::Image_``), so Cyclone's own
  serialiser reads what the nodes write — an independent decoder of their bytes.
* :class:`RawWriter` sends bytes a well-behaved writer never would. Cyclone refuses to write
  bytes that are not CDR of its topic type, so the writer's type is a byte sequence under the
  ROS type's name: the reader gets the sequence's length where it expects the message's first
  word (``header.stamp.sec`` in every type the nodes read) and every other byte as given.
"""

from __future__ import annotations

import functools
import os
import struct
from typing import Any

import cyclonedds._clayer as _clayer
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from rosidl_parser import definition as d

#: Cyclone on the loopback interface only, unicast discovery to this machine (the nodes'
#: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST answers there)
LOOPBACK_CONFIG = """<CycloneDDS><Domain Id="any"><General>
<Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast>
<MaxMessageSize>65000B</MaxMessageSize></General>
<Internal><SocketReceiveBufferSize min="4MB"/></Internal>
<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>60</MaxAutoParticipantIndex>
<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>"""

_BASIC = {"boolean": bool, "octet": t.byte, "char": t.uint8, "uint8": t.uint8,
          "int8": t.int8, "uint16": t.uint16, "int16": t.int16, "uint32": t.uint32,
          "int32": t.int32, "uint64": t.uint64, "int64": t.int64, "float": t.float32,
          "double": t.float64}


def participant(domain_id: int) -> DomainParticipant:
    """A Cyclone participant on ``domain_id`` that talks over loopback."""
    os.environ["CYCLONEDDS_URI"] = LOOPBACK_CONFIG
    return DomainParticipant(domain_id)


def delete(dp: DomainParticipant) -> None:
    """Delete ``dp`` and every reader and writer under it now, not whenever the garbage
    collector comes to it: a participant left alive on a domain id its test gave back would
    be heard, with a transient-local writer's history, by the next run that drew the id."""
    dp.__del__()


def _annotation(kind: Any) -> Any:
    if isinstance(kind, d.BasicType):
        return _BASIC[kind.typename]
    if isinstance(kind, d.UnboundedString | d.UnboundedWString):
        return str
    if isinstance(kind, d.BoundedString):
        return t.bounded_str[kind.maximum_size]
    if isinstance(kind, d.NamespacedType):
        module = __import__(f"{kind.namespaces[0]}.msg", fromlist=[kind.name])
        return idl_type(getattr(module, kind.name))
    if isinstance(kind, d.Array):
        return t.array[_annotation(kind.value_type), kind.size]
    if isinstance(kind, d.BoundedSequence):
        return t.sequence[_annotation(kind.value_type), kind.maximum_size]
    if isinstance(kind, d.UnboundedSequence):
        return t.sequence[_annotation(kind.value_type)]
    raise TypeError(f"no Cyclone type for {kind!r}")


def dds_type_name(cls: type) -> str:
    return f"{cls.__module__.split('.')[0]}::msg::dds_::{cls.__name__}_"


@functools.cache
def idl_type(cls: type) -> type[IdlStruct]:
    """Cyclone's struct for the ROS message class ``cls`` (nested types reused)."""
    fields = {name: _annotation(kind)
              for name, kind in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES,
                                    strict=True)}
    return make_idl_struct(f"{cls.__name__}_", dds_type_name(cls), fields
                           or {"structure_needs_at_least_one_member": t.uint8})


def xcdr1_qos(*policies: Any) -> Qos:
    return Qos(Policy.DataRepresentation(use_cdrv0_representation=True), *policies)


def reader(dp: DomainParticipant, topic: str, cls: type, *policies: Any) -> DataReader:
    """A Cyclone reader of ROS topic ``topic`` (absolute name) with ``cls``'s type."""
    return DataReader(dp, Topic(dp, "rt" + topic, idl_type(cls)), qos=xcdr1_qos(*policies))


def take_all(rd: DataReader, cls: type) -> list[Any]:
    """Every valid sample ``rd`` holds, decoded by Cyclone's own deserialiser."""
    struct_type = idl_type(cls)
    return [s for s in rd.take(N=256) if isinstance(s, struct_type)]


class RawWriter:
    """Writes arbitrary bytes on a ROS topic, as the samples of ``cls``'s type name."""

    def __init__(self, dp: DomainParticipant, topic: str, cls: type, depth: int = 200,
                 transient_local: bool = False) -> None:
        blob = make_idl_struct(f"{cls.__name__}_", dds_type_name(cls),
                               {"blob": t.sequence[t.uint8]})
        durability = (Policy.Durability.TransientLocal if transient_local
                      else Policy.Durability.Volatile)   # a transient-local reader needs one
        self.writer = DataWriter(dp, Topic(dp, "rt" + topic, blob), qos=xcdr1_qos(
            Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(depth),
            durability))

    def matched(self) -> int:
        return len(self.writer.get_matched_subscriptions())

    def write(self, sample: bytes) -> None:
        """Send ``sample`` (a 4-byte encapsulation header and the body) as it is, except that
        the body's first word becomes the body's length minus 4 (the byte sequence's length
        field, the one word this writer cannot choose)."""
        body = sample[4:]
        if len(body) < 4:
            body = body + b"\x00" * (4 - len(body))
        raw = b"\x00\x01\x00\x00" + struct.pack("<I", len(body) - 4) + body[4:]
        raw += b"\x00" * ((-len(raw)) % 4)
        ret = _clayer.ddspy_write(self.writer._ref, raw)
        if ret < 0:
            raise RuntimeError(f"Cyclone refused a {len(raw)}-byte sample (code {ret})")
