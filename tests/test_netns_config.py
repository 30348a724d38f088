"""What the multi-host harness configures, checked without root: each host's Fast DDS profile
and discovery peers, its addresses, and the loss program's bytecode."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from twinslam.hosts.ebpf_loss import random_drop_program
from twinslam.hosts.fastdds import PROFILE, ros_env
from twinslam.hosts.netns import HOST_PROFILE, HOSTS, NetnsHosts, address_of, host_env

NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_each_host_speaks_udp_only_below_the_mtu_to_static_peers(tmp_path) -> None:
    root = ET.fromstring(HOST_PROFILE)
    transports = root.findall("f:profiles/f:transport_descriptors/f:transport_descriptor", NS)
    assert [t.findtext("f:type", namespaces=NS) for t in transports] == ["UDPv4"]  # no SHM
    assert int(transports[0].findtext("f:maxMessageSize", namespaces=NS)) <= 1472
    rtps = root.find("f:profiles/f:participant/f:rtps", NS)
    assert rtps.findtext("f:useBuiltinTransports", namespaces=NS) == "false"
    env = host_env(42, tmp_path / "p.xml")
    peers = env["ROS_STATIC_PEERS"].split(";")
    assert peers == [address_of(h) for h in HOSTS]
    assert all(a.startswith("10.210.0.") for a in peers)            # private, namespaces only
    assert len(set(peers)) == 3
    assert env["ROS_DOMAIN_ID"] == "42" and env["FASTRTPS_DEFAULT_PROFILES_FILE"].endswith("p.xml")


def test_hosts_are_named_by_prefix_and_unknown_hosts_are_refused() -> None:
    hosts = NetnsHosts(prefix="x-")
    assert hosts.namespaces == {"device": "x-device", "edge": "x-edge", "twin": "x-twin"}
    assert hosts.command("edge", ["tc"]) == ["ip", "netns", "exec", "x-edge", "tc"]
    with pytest.raises(ValueError, match="unknown host 'cloud'"):
        hosts.command("cloud", ["tc"])
    with pytest.raises(ValueError, match="unknown host"):
        address_of("cloud")


def test_loss_program_drops_below_the_threshold_and_refuses_large_loss() -> None:
    code = random_drop_program(5.0)
    insns = [struct.unpack("<BBhi", code[i:i + 8]) for i in range(0, len(code), 8)]
    assert [op for op, *_ in insns] == [0x85, 0x25, 0xB7, 0x95, 0xB7, 0x95]
    assert insns[0][3] == 7                                  # bpf_get_prandom_u32
    assert insns[1][3] == int(0.05 * 2**32)                  # if r0 > 5 % of 2^32: pass
    assert insns[2][3] == 2 and insns[4][3] == 0             # TC_ACT_SHOT, TC_ACT_OK
    with pytest.raises(ValueError, match="loss must be in"):
        random_drop_program(50.0)


@pytest.mark.parametrize("which", ["project", "host"])
def test_fast_dds_accepts_every_element_of_the_profiles(which: str, tmp_path) -> None:
    """Fast DDS reports an element it does not know on stdout and goes on without the whole
    profile (the transports, announcement period and heartbeat would silently be its defaults):
    a node started with each profile must print no parser error."""
    path = PROFILE
    if which == "host":
        path = tmp_path / "host.xml"
        path.write_text(HOST_PROFILE, encoding="utf-8")
    env = dict(os.environ, **ros_env(231, profile=path))   # nothing is exchanged: no peer needed
    code = ("import rclpy; from std_msgs.msg import String; rclpy.init(); "
            "n = rclpy.create_node('profile_check'); n.create_publisher(String, 'p', 1); "
            "rclpy.shutdown()")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60)
    said = done.stdout + done.stderr
    assert done.returncode == 0, said
    assert "XMLPARSER" not in said and "Error" not in said, said


def test_a_fleets_hosts_get_addresses_of_their_own_and_the_edge_keeps_its_own() -> None:
    from twinslam.hosts.netns import SUBNET

    fleet = NetnsHosts(prefix="tq-", hosts=("ar1", "ar2", "edge"))
    assert [fleet.address(h) for h in ("ar1", "ar2", "edge")] == [
        f"{SUBNET}.10", f"{SUBNET}.11", address_of("edge")]
    env = fleet.env_for("ar1")
    assert all(fleet.address(h) in env["ROS_STATIC_PEERS"] for h in fleet.hosts)
    with pytest.raises(ValueError, match="unknown host 'twin'"):
        fleet.address("twin")
