"""``twinslam nodes``: the ROS graph's nodes on $ROS_DOMAIN_ID, as ``ros2 node list``."""

from __future__ import annotations

import argparse

from twinslam.cli.console import Subparsers, error
from twinslam.hosts.fastdds import domain_id_from_env
from twinslam.node_runtime.session import RosSession


def run(args: argparse.Namespace) -> int:
    """The ROS graph's nodes on $ROS_DOMAIN_ID, as ``ros2 node list`` prints them."""

    try:
        domain_id_from_env()
    except ValueError as exc:
        return error(exc)
    session = RosSession("twinslam_nodes")
    try:
        session.spin_until(lambda: False, args.timeout)     # let discovery run
        names = sorted(f"{ns.rstrip('/')}/{name}" for name, ns in
                       session.node.get_node_names_and_namespaces()
                       if name != "twinslam_nodes")
    finally:
        session.close()
    for name in names:
        print(name)
    return 0


def register(sub: Subparsers) -> None:
    nodes = sub.add_parser("nodes", help="list the nodes on $ROS_DOMAIN_ID (like ros2 node list)")
    nodes.add_argument("--timeout", type=float, default=3.5,
                       help="seconds of discovery before listing (default 3.5: a node announces "
                       "itself every 3 s at Fast DDS's defaults, every 1 s with the project's "
                       "profile; a shorter wait can miss nodes)")
    nodes.set_defaults(func=run)
