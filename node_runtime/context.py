"""The process-wide context: one DDS participant, the ROS arguments, shutdown and discovery info.

As in rmw_cyclonedds, all nodes of a process share one domain participant (USER_DATA
``enclave=/;``), and the participant announces its nodes and their endpoints on
``ros_discovery_info`` so that ``ros2 node list`` on a ROS 2 host shows them.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from typing import TYPE_CHECKING, Any

import numpy as np
from cyclonedds.core import DDSException, GuardCondition
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.topic import Topic

from msg_schemas import cdr
from msg_schemas.dds_types import dds_type
from msg_schemas.registry import new, type_hash
from node_runtime.arguments import RosArguments, parse_ros_args
from node_runtime.qos import LATCHED
from node_runtime.wire import write_raw

if TYPE_CHECKING:
    from node_runtime.node import Node

DISCOVERY_TOPIC = "ros_discovery_info"
DISCOVERY_TYPE = "rmw_dds_common/msg/ParticipantEntitiesInfo"


class RuntimeStateError(RuntimeError):
    """Using the runtime before ``init()`` or after ``shutdown()``."""


class DomainJoinError(RuntimeError):
    """Cyclone refused to create the participant; the message says what to check."""


def participant_failure(domain_id: int, exc: Exception) -> str:
    """Why joining ``domain_id`` failed, in words a user can act on (Cyclone only says
    "non specific error" and prints its configuration complaint to stderr)."""
    uri = os.environ.get("CYCLONEDDS_URI", "")
    if "<Security" in uri:
        return ("CYCLONEDDS_URI has a <Security> section, but the cyclonedds wheel is built "
                "without the DDS Security plugins (auth, access control, crypto): remove the "
                "section, or build Cyclone DDS with ENABLE_SECURITY and its Python binding "
                "against it (README, Security)")
    where = "CYCLONEDDS_URI" if uri else "Cyclone's default configuration"
    return (f"could not join DDS domain {domain_id} ({exc}); check {where}: the interface it "
            "names must exist on this host, and the XML must be valid (Cyclone printed its "
            "complaint above)")


def gid_message(guid: Any) -> Any:
    """An ``rmw_dds_common/Gid`` holding a DDS GUID (16 bytes in Jazzy)."""
    return new("rmw_dds_common/msg/Gid", data=np.frombuffer(guid.bytes, dtype=np.uint8).copy())


def domain_id_from_env() -> int:
    raw = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return 0
    try:
        value = int(raw)
    except ValueError:
        raise ValueError(f"ROS_DOMAIN_ID={raw!r} is not an integer") from None
    if not 0 <= value <= 232:
        raise ValueError(f"ROS_DOMAIN_ID={value} is outside 0..232")
    return value


class Context:
    """State shared by all nodes of one process between ``init()`` and ``shutdown()``."""

    def __init__(self, argv: list[str], domain_id: int | None = None) -> None:
        self.ros_args: RosArguments = parse_ros_args(argv)
        self.domain_id = domain_id_from_env() if domain_id is None else domain_id
        try:
            self.participant = DomainParticipant(self.domain_id,
                                                 qos=Qos(Policy.Userdata(b"enclave=/;")))
        except DDSException as exc:
            raise DomainJoinError(participant_failure(self.domain_id, exc)) from None
        self.gid = self.participant.get_guid()
        self.guard = GuardCondition(self.participant)
        self._shutdown = threading.Event()
        self._lock = threading.Lock()
        self._nodes: list[Node] = []
        topic = Topic(self.participant, DISCOVERY_TOPIC, dds_type(DISCOVERY_TYPE))
        self._discovery_writer = DataWriter(self.participant, topic,
                                            qos=LATCHED.to_dds(type_hash(DISCOVERY_TYPE)))
        self._publish_discovery()

    # -- lifecycle -------------------------------------------------------------------------

    def ok(self) -> bool:
        return not self._shutdown.is_set()

    def request_shutdown(self) -> None:
        """Ask every spin loop to return (safe from signal handlers and other threads)."""
        self._shutdown.set()
        self.guard.set(True)

    def wait_for_shutdown(self, timeout: float | None = None) -> bool:
        return self._shutdown.wait(timeout)

    # -- discovery -------------------------------------------------------------------------

    def register_node(self, node: Node) -> None:
        with self._lock:
            self._nodes.append(node)
        self._publish_discovery()

    def unregister_node(self, node: Node) -> None:
        with self._lock:
            if node in self._nodes:
                self._nodes.remove(node)
        self._publish_discovery()

    def entities_changed(self) -> None:
        self._publish_discovery()

    def _publish_discovery(self) -> None:
        with self._lock:
            infos = [
                new("rmw_dds_common/msg/NodeEntitiesInfo",
                    node_namespace=node.get_namespace(), node_name=node.get_name(),
                    reader_gid_seq=[gid_message(g) for g in node._reader_gids()],
                    writer_gid_seq=[gid_message(g) for g in node._writer_gids()])
                for node in self._nodes
            ]
            msg = new(DISCOVERY_TYPE, gid=gid_message(self.gid), node_entities_info_seq=infos)
            write_raw(self._discovery_writer, cdr.serialize(msg))

    def close(self) -> None:
        self.request_shutdown()
        with self._lock:
            nodes = list(self._nodes)
        for node in nodes:
            node.destroy_node()
        self.participant = None  # type: ignore[assignment]


_context: Context | None = None


def init(args: list[str] | None = None, domain_id: int | None = None,
         install_signal_handlers: bool = True) -> Context:
    """Start the runtime for this process (like ``rclpy.init``); ``args`` default to sys.argv."""
    global _context
    if _context is not None and _context.ok():
        raise RuntimeStateError("init() was already called; call shutdown() first")
    _context = Context(list(sys.argv if args is None else args), domain_id)
    if install_signal_handlers and threading.current_thread() is threading.main_thread():
        ctx = _context

        def _on_signal(signum: int, _frame: Any) -> None:
            ctx.request_shutdown()

        signal.signal(signal.SIGINT, _on_signal)
        signal.signal(signal.SIGTERM, _on_signal)
    return _context


def get_context() -> Context:
    if _context is None:
        raise RuntimeStateError("call node_runtime.init() before creating nodes")
    return _context


def ok() -> bool:
    return _context is not None and _context.ok()


def shutdown() -> None:
    """Stop all spin loops, destroy the nodes and leave the DDS domain."""
    global _context
    if _context is not None:
        _context.close()
        _context = None
