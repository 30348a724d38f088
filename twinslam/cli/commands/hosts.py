"""``twinslam hosts``: device, edge and twin hosts as network namespaces (root)."""

from __future__ import annotations

import argparse
import sys

from twinslam.cli.console import Subparsers
from twinslam.hosts.netns import (
    HOST_PROFILE,
    HOSTS,
    NetnsError,
    NetnsHosts,
    address_of,
    unavailable_reason,
)


def run(args: argparse.Namespace) -> int:
    """Build or remove the three test hosts (network namespaces) and say how to use them."""

    hosts = NetnsHosts(prefix=args.prefix)
    if args.action == "down":
        hosts.down()
        left = hosts.exists()
        print("removed" if not left else f"could not remove {', '.join(left)}")
        return 0 if not left else 1
    if args.action == "config":
        print(HOST_PROFILE)
        return 0
    why = unavailable_reason()
    if why:
        print(f"twinslam hosts: {why}", file=sys.stderr)
        return 2
    try:
        hosts.up()
    except NetnsError as exc:
        print(f"twinslam hosts: {exc}", file=sys.stderr)
        return 1
    for host in HOSTS:
        print(f"{host:<7} netns {hosts.namespaces[host]:<20} eth0 {address_of(host)}/24")
    peers = ";".join(address_of(h) for h in HOSTS)
    print("\nrun a node on a host, e.g.:\n"
          "  twinslam hosts config > /tmp/fastdds_host.xml\n"
          "  export FASTRTPS_DEFAULT_PROFILES_FILE=/tmp/fastdds_host.xml "
          f"ROS_STATIC_PEERS='{peers}'\n"
          f"  ip netns exec {hosts.namespaces['edge']} .venv/bin/python -m edge_mapper.node\n"
          f"shape the device's uplink: ip netns exec {hosts.namespaces['device']} "
          "tc qdisc replace dev eth0 root tbf rate 40mbit burst 64kb latency 500ms "
          "(or device_tracker -p shaper:=tc)")
    return 0


def register(sub: Subparsers) -> None:
    hosts = sub.add_parser("hosts", help="device, edge and twin hosts as network namespaces "
                           "(root)")
    hosts.add_argument("action", choices=["up", "down", "config"],
                       help="build them, remove them, or print a host's Fast DDS profile")
    hosts.add_argument("--prefix", default="", help="namespace name prefix (default none: "
                       "device, edge, twin, switch)")
    hosts.set_defaults(func=run)
