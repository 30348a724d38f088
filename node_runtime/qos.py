"""ROS 2 QoS profiles and their translation to Cyclone DDS policies.

Profiles mirror rclpy's presets: ``SENSOR_DATA`` (best effort, keep last 5) for images,
``DEFAULT`` (reliable, keep last 10) for control topics, and ``LATCHED`` (reliable, transient
local, keep last 1) for state a late joiner must see, such as ``ros_discovery_info`` or the map.
Every writer and reader also gets XCDR1 data representation and the ``typehash=RIHS01_...;``
user data that ROS 2 Jazzy endpoints carry.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration


class Reliability(Enum):
    RELIABLE = "reliable"
    BEST_EFFORT = "best_effort"


class Durability(Enum):
    VOLATILE = "volatile"
    TRANSIENT_LOCAL = "transient_local"


@dataclass(frozen=True)
class QoSProfile:
    """History depth (KEEP_LAST), reliability and durability, as ROS 2 users set them."""

    depth: int = 10
    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE

    def to_dds(self, type_hash: str) -> Qos:
        policies = [
            Policy.History.KeepLast(self.depth),
            Policy.DataRepresentation(use_cdrv0_representation=True),
            Policy.Userdata(f"typehash={type_hash};".encode()),
        ]
        if self.reliability is Reliability.RELIABLE:
            policies.append(Policy.Reliability.Reliable(duration(seconds=1)))
        else:
            policies.append(Policy.Reliability.BestEffort)
        if self.durability is Durability.TRANSIENT_LOCAL:
            policies.append(Policy.Durability.TransientLocal)
        else:
            policies.append(Policy.Durability.Volatile)
        return Qos(*policies)


DEFAULT = QoSProfile()
SENSOR_DATA = QoSProfile(depth=5, reliability=Reliability.BEST_EFFORT)
LATCHED = QoSProfile(depth=1, durability=Durability.TRANSIENT_LOCAL)
#: the per-slot protocol topics: reliable, and deep enough that a slow slot (a retrain, a bundle
#: adjustment next door) loses nothing — a KEEP_LAST 10 queue dropped 11 slots in a test
PROTOCOL = QoSProfile(depth=100)
