"""Reading the ROS graph from ``ros_discovery_info``: which nodes are up, with which endpoints.

This is what ``ros2 node list`` consults on a ROS 2 host; ``twinslam nodes`` uses it where ROS 2
is not installed. Samples are decoded with the same codec as every other message.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from msg_schemas import cdr
from msg_schemas.dds_types import dds_type
from msg_schemas.registry import type_hash
from node_runtime.context import DISCOVERY_TOPIC, DISCOVERY_TYPE
from node_runtime.qos import Durability, QoSProfile
from node_runtime.wire import take_raw

#: ros_discovery_info is keyless: every participant's sample lands in the one instance, so a
#: KEEP_LAST 1 reader would keep only the newest participant's. Readers keep a deep history;
#: writers stay KEEP_LAST 1 as ROS 2 expects.
GRAPH_READER_QOS = QoSProfile(depth=256, durability=Durability.TRANSIENT_LOCAL)


@dataclass(frozen=True)
class GraphNode:
    """One node as announced by its participant."""

    namespace: str
    name: str
    participant_gid: bytes
    reader_gids: tuple[bytes, ...]
    writer_gids: tuple[bytes, ...]

    @property
    def fully_qualified_name(self) -> str:
        return self.namespace.rstrip("/") + "/" + self.name


class GraphMonitor:
    """Keeps the latest ``ParticipantEntitiesInfo`` of every participant on a domain."""

    def __init__(self, participant: DomainParticipant) -> None:
        topic = Topic(participant, DISCOVERY_TOPIC, dds_type(DISCOVERY_TYPE))
        self._reader = DataReader(participant, topic,
                                  qos=GRAPH_READER_QOS.to_dds(type_hash(DISCOVERY_TYPE)))
        self._latest: dict[bytes, list[GraphNode]] = {}

    def poll(self) -> None:
        for data in take_raw(self._reader, batch=64):
            try:
                msg = cdr.deserialize(data, DISCOVERY_TYPE)
            except cdr.CdrError:
                continue
            gid = bytes(msg.gid.data)
            self._latest[gid] = [
                GraphNode(n.node_namespace, n.node_name, gid,
                          tuple(bytes(g.data) for g in n.reader_gid_seq),
                          tuple(bytes(g.data) for g in n.writer_gid_seq))
                for n in msg.node_entities_info_seq
            ]

    def nodes(self) -> list[GraphNode]:
        self.poll()
        return sorted((n for nodes in self._latest.values() for n in nodes),
                      key=lambda n: n.fully_qualified_name)

    def wait_for(self, names: set[str], timeout: float) -> bool:
        """Wait until every fully qualified name in ``names`` is announced (bounded)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if names <= {n.fully_qualified_name for n in self.nodes()}:
                return True
            time.sleep(0.05)
        return names <= {n.fully_qualified_name for n in self.nodes()}
