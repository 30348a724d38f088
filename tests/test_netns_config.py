"""What the multi-host harness configures, checked without root: each host's Cyclone
configuration, its addresses, and the loss program's bytecode."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET

import pytest

from node_runtime.ebpf_loss import random_drop_program
from node_runtime.netns import HOSTS, NetnsHosts, address_of, cyclone_config

NS = {"c": "https://cdds.io/config"}


def test_each_host_speaks_unicast_on_its_own_interface_below_the_mtu() -> None:
    root = ET.fromstring(cyclone_config("eth0"))
    general = root.find("c:Domain/c:General", NS)
    assert general is not None
    assert general.find("c:Interfaces/c:NetworkInterface", NS).get("name") == "eth0"
    assert general.findtext("c:AllowMulticast", namespaces=NS) == "false"
    assert int(general.findtext("c:MaxMessageSize", namespaces=NS).rstrip("B")) <= 1472
    peers = [p.get("address") for p in root.findall("c:Domain/c:Discovery/c:Peers/c:Peer", NS)]
    assert peers == [address_of(h) for h in HOSTS]
    assert all(a.startswith("10.210.0.") for a in peers)            # private, namespaces only
    assert len(set(peers)) == 3


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
