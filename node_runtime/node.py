"""``Node``: publishers, subscriptions, timers, parameters and a logger, shaped like rclpy's.

A publisher encodes with :mod:`msg_schemas.cdr` and hands the bytes to Cyclone as they are; a
subscription takes raw samples from Cyclone, decodes and validates them, and queues nothing on
Cyclone's threads: the executor (:mod:`node_runtime.executor`) calls the user's callback on the
spin thread. A sample that fails decoding or validation is logged, counted and dropped; the
subscription keeps going.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import ReadCondition
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from msg_schemas import cdr
from msg_schemas.dds_types import dds_type
from msg_schemas.registry import type_hash
from msg_schemas.validation import MessageError, validate
from node_runtime.context import Context, get_context
from node_runtime.log import RcutilsLogger
from node_runtime.names import (
    dds_topic_name,
    expand_topic_name,
    normalize_namespace,
    remap_topic,
    validate_node_name,
)
from node_runtime.parameters import Parameter, ParameterError, load_params_file
from node_runtime.qos import DEFAULT, QoSProfile
from node_runtime.wire import ANY_STATE, take_raw, write_raw


def _msg_type_name(msg_type: Any) -> str:
    name = getattr(msg_type, "__msgtype__", None)
    if isinstance(msg_type, str):
        return msg_type
    if name is None:
        raise TypeError(f"{msg_type!r} is not a message class of msg_schemas")
    return name


class Publisher:
    """Writes messages of one type on one topic (``publish``, ``get_subscription_count``)."""

    def __init__(self, node: Node, type_name: str, topic: str, qos: QoSProfile) -> None:
        self.msg_type = type_name
        self.topic_name = topic
        self._codec = cdr.compiled(type_name)
        dds_topic = Topic(node.context.participant, dds_topic_name(topic), dds_type(type_name))
        self._writer = DataWriter(node.context.participant, dds_topic,
                                  qos=qos.to_dds(type_hash(type_name)))

    def publish(self, msg: Any) -> None:
        write_raw(self._writer, self.encode(msg))

    def encode(self, msg: Any) -> bytes:
        """The CDR bytes ``publish`` would write (to write later with ``publish_raw``)."""
        if getattr(msg, "__msgtype__", None) != self.msg_type:
            raise TypeError(f"publisher on {self.topic_name} takes {self.msg_type}, got "
                            f"{getattr(msg, '__msgtype__', type(msg).__name__)}")
        return self._codec.serialize(msg)

    def publish_raw(self, payload: bytes) -> None:
        """Write already-encoded CDR bytes (tests and bridges use this)."""
        write_raw(self._writer, payload)

    def get_subscription_count(self) -> int:
        return len(self._writer.get_matched_subscriptions())

    def wait_for_acknowledgments(self, timeout_sec: float) -> bool:
        """Block until every reliable reader has acknowledged what was published (or the
        timeout passes); a process that is about to exit calls this so its last samples are
        not lost with its participant. Returns whether all were acknowledged."""
        return bool(self._writer.wait_for_acks(duration(seconds=timeout_sec)))

    @property
    def gid(self) -> Any:
        return self._writer.get_guid()


class Subscription:
    """Receives one topic; decoding and validation failures are logged and counted."""

    def __init__(self, node: Node, type_name: str, topic: str, callback: Callable[[Any], None],
                 qos: QoSProfile, raw: bool = False) -> None:
        self.msg_type = type_name
        self.topic_name = topic
        self.callback = callback
        self.raw = raw
        self.rejected = 0
        self.received = 0
        self._node = node
        self._codec = cdr.compiled(type_name)
        dds_topic = Topic(node.context.participant, dds_topic_name(topic), dds_type(type_name))
        self._reader = DataReader(node.context.participant, dds_topic,
                                  qos=qos.to_dds(type_hash(type_name)))
        self.condition = ReadCondition(self._reader, ANY_STATE)

    def get_publisher_count(self) -> int:
        return len(self._reader.get_matched_publications())

    @property
    def gid(self) -> Any:
        return self._reader.get_guid()

    def take_and_dispatch(self) -> int:
        """Take what Cyclone holds, run the callback per good sample; returns samples handled."""
        handled = 0
        for data in take_raw(self._reader):
            handled += 1
            self.handle(data)
        return handled

    def handle(self, data: bytes) -> bool:
        """One sample as it came off the wire: decoded, validated and given to the callback,
        or rejected with a logged error; returns whether the callback ran."""
        if self.raw:
            self.received += 1
            self.callback(data)
            return True
        try:
            msg = self._codec.deserialize(data)
            validate(self.msg_type, msg)
        except (cdr.CdrError, MessageError) as exc:
            self.rejected += 1
            self._node.get_logger().error(
                f"dropped a malformed {self.msg_type} on {self.topic_name} "
                f"({len(data)} bytes): {exc}")
            return False
        self.received += 1
        self.callback(msg)
        return True


class Timer:
    """Calls ``callback`` every ``period`` seconds on the spin thread."""

    def __init__(self, period: float, callback: Callable[[], None]) -> None:
        if not period > 0:
            raise ValueError(f"timer period must be > 0 s, got {period}")
        self.period = period
        self.callback = callback
        self.next_due = time.monotonic() + period
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class Node:
    """A ROS 2 node on the process's DDS participant (``node_runtime.init()`` first)."""

    def __init__(self, node_name: str, *, namespace: str = "",
                 context: Context | None = None) -> None:
        self.context = context or get_context()
        args = self.context.ros_args
        validate_node_name(node_name)
        self._name = validate_node_name(args.special("__node", node_name) or node_name)
        ns = args.special("__ns", node_name)
        self._namespace = normalize_namespace(ns if ns is not None else namespace)
        self._logger = RcutilsLogger(self._name, args.log_level or "info")
        self.publishers: list[Publisher] = []
        self.subscriptions: list[Subscription] = []
        self.timers: list[Timer] = []
        self._parameters: dict[str, Parameter] = {}
        self._overrides = self._collect_parameter_overrides(node_name)
        self._destroyed = False
        self.context.register_node(self)

    # -- identity ----------------------------------------------------------------------------

    def get_name(self) -> str:
        return self._name

    def get_namespace(self) -> str:
        return self._namespace

    def get_fully_qualified_name(self) -> str:
        return self._namespace.rstrip("/") + "/" + self._name

    def get_logger(self) -> RcutilsLogger:
        return self._logger

    def resolve_topic_name(self, topic: str) -> str:
        """Expanded and remapped name of ``topic`` as this node would use it."""
        full = expand_topic_name(topic, self._name, self._namespace)
        return remap_topic(full, self.context.ros_args.remaps, self._name, self._namespace)

    # -- endpoints ---------------------------------------------------------------------------

    def create_publisher(self, msg_type: Any, topic: str,
                         qos_profile: QoSProfile | int = DEFAULT) -> Publisher:
        qos = QoSProfile(depth=qos_profile) if isinstance(qos_profile, int) else qos_profile
        pub = Publisher(self, _msg_type_name(msg_type), self.resolve_topic_name(topic), qos)
        self.publishers.append(pub)
        self.context.entities_changed()
        return pub

    def create_subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None],
                            qos_profile: QoSProfile | int = DEFAULT, *,
                            raw: bool = False) -> Subscription:
        """Subscribe; ``raw=True`` hands the callback the CDR bytes instead of a message."""
        qos = QoSProfile(depth=qos_profile) if isinstance(qos_profile, int) else qos_profile
        sub = Subscription(self, _msg_type_name(msg_type), self.resolve_topic_name(topic),
                           callback, qos, raw)
        self.subscriptions.append(sub)
        self.context.entities_changed()
        self.context.guard.set(True)  # let a running executor attach the new reader
        return sub

    def create_timer(self, timer_period_sec: float, callback: Callable[[], None]) -> Timer:
        timer = Timer(timer_period_sec, callback)
        self.timers.append(timer)
        self.context.guard.set(True)
        return timer

    def _reader_gids(self) -> list[Any]:
        return [s.gid for s in self.subscriptions]

    def _writer_gids(self) -> list[Any]:
        return [p.gid for p in self.publishers]

    # -- parameters --------------------------------------------------------------------------

    def _collect_parameter_overrides(self, original_name: str) -> dict[str, Any]:
        args = self.context.ros_args
        out: dict[str, Any] = {}
        for path in args.params_files:
            out.update(load_params_file(path, self.get_fully_qualified_name()))
        for node, name, value in args.params:
            if node is None or node in (original_name, self._name):
                out[name] = value
        return out

    def declare_parameter(self, name: str, default_value: Any = None) -> Parameter:
        """Declare ``name``; a value from ``-p`` or ``--params-file`` overrides the default.

        The override must have the default's type (ints are accepted for floats), so that a
        typo such as ``-p rate:=fast`` fails at start-up with a clear message.
        """
        if name in self._parameters:
            raise ParameterError(f"parameter {name!r} is already declared")
        value = self._overrides.get(name, default_value)
        if default_value is not None and value is not None:
            if isinstance(default_value, float) and isinstance(value, int) \
                    and not isinstance(value, bool):
                value = float(value)
            elif type(value) is not type(default_value):
                raise ParameterError(
                    f"parameter {name!r} of node {self._name} expects "
                    f"{type(default_value).__name__}, got {value!r} ({type(value).__name__})")
        param = Parameter(name, value)
        self._parameters[name] = param
        return param

    def has_parameter(self, name: str) -> bool:
        return name in self._parameters

    def get_parameter(self, name: str) -> Parameter:
        try:
            return self._parameters[name]
        except KeyError:
            raise ParameterError(f"parameter {name!r} of node {self._name} "
                                 "is not declared") from None

    def set_parameter(self, name: str, value: Any) -> None:
        self.get_parameter(name)
        self._parameters[name] = Parameter(name, value)

    # -- teardown ----------------------------------------------------------------------------

    def destroy_node(self) -> None:
        if self._destroyed:
            return
        self._destroyed = True
        for timer in self.timers:
            timer.cancel()
        self.context.unregister_node(self)
        self.publishers.clear()
        self.subscriptions.clear()
