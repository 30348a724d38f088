"""The DDS environment of a node process: domain, discovery range and the Fast DDS profile.

rmw_fastrtps_cpp reads these at ``rclpy.init``: ``ROS_DOMAIN_ID``;
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps discovery on this machine (tests and the
loopback demo, so parallel runs never cross); ``ROS_STATIC_PEERS`` names unicast peers where
multicast does not reach; ``FASTRTPS_DEFAULT_PROFILES_FILE`` the transport profile
(``config/fastdds.xml``: shared memory large enough for camera frames, big UDP buffers).
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
#: the profile the nodes use by default (shared memory + UDPv4, sized for images)
PROFILE = REPO_ROOT / "config" / "fastdds.xml"
ENV_KEYS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS",
            "FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION")


def installed_profile() -> Path:
    """``config/fastdds.xml`` from the source tree, else from the installed package's share."""
    if PROFILE.is_file():
        return PROFILE
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("twinslam")) / "config" / "fastdds.xml"


def ros_env(domain_id: int, discovery_range: str = "LOCALHOST",
            profile: Path | None = None, static_peers: tuple[str, ...] = ()) -> dict[str, str]:
    """The variables a node process on ``domain_id`` needs (merge them into an environment)."""
    env = {"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": discovery_range,
           "FASTRTPS_DEFAULT_PROFILES_FILE": str(profile or installed_profile()),
           "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    if static_peers:
        env["ROS_STATIC_PEERS"] = ";".join(static_peers)
    return env


def domain_id_from_env() -> int:
    """``$ROS_DOMAIN_ID`` (0 when unset), refused with a reason outside ROS 2's 0..232."""
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
