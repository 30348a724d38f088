"""A second DDS vendor as the nodes' outside peer: Cyclone DDS (``tests.cyclone_peer``), not
rclpy, reads the player's camera images and sees the nodes in ``ros_discovery_info`` — the
interoperability a ROS 2 host on another middleware, or a plain DDS application, relies on."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from cyclonedds.qos import Policy
from cyclonedds.util import duration
from rmw_dds_common.msg import ParticipantEntitiesInfo
from sensor_msgs.msg import Image

from tests import cyclone_peer
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes

#: node processes forked as the launchers fork theirs (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


def test_cyclone_reads_the_players_640x480_images(domain: LoopbackDomain,
                                                  cyclone: Callable[[], Any]) -> None:
    """Every image after the writer's first. Cyclone's reliable volatile reader misses the
    first sample of a Fast DDS writer (measured: 29 of 30 in every run, with and without the
    project's Fast DDS profile, with 1 s or 3 s of discovery settling before the first frame);
    an rclpy reader gets all 30 (test_sequence_player)."""
    dp = cyclone()
    rd = cyclone_peer.reader(dp, "/camera/image_raw", Image,
                             Policy.Reliability.Reliable(duration(seconds=1)),
                             Policy.History.KeepLast(100))
    player = domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args", "-p",
                           "sequence:=synthetic:30", "-p", "rate:=2.0",
                           "-p", "wait_for_subscribers:=1"], forks=FORKS)
    got: list = []
    deadline = time.monotonic() + 60
    quiet_since = None                         # the player has exited: 2 s more to arrive
    while time.monotonic() < deadline and len(got) < 30:
        new = cyclone_peer.take_all(rd, Image)
        got += new
        if player.poll() is not None:
            quiet_since = quiet_since if quiet_since and not new else time.monotonic()
            if time.monotonic() - quiet_since > 2.0:
                break
        time.sleep(0.05)
    code, _, err = domain.stop(player)
    assert code == 0, err[-2000:]
    assert len(got) >= 29, f"Cyclone received {len(got)} of 30 images"
    first = got[0]
    assert (first.width, first.height, first.encoding, first.step) == (640, 480, "rgb8", 1920)
    assert all(len(img.data) == 640 * 480 * 3 for img in got)
    stamps = [img.header.stamp.sec + img.header.stamp.nanosec * 1e-9 for img in got]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(got)
    gaps = np.diff(stamps)
    assert max(gaps) < 1.5 / 60, "consecutive frames (30 Hz played at 2x)"


def test_cyclone_sees_the_nodes_in_ros_discovery_info(domain: LoopbackDomain,
                                                      cyclone: Callable[[], Any]) -> None:
    dp = cyclone()
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    rd = DataReader(dp, Topic(dp, "ros_discovery_info",
                              cyclone_peer.idl_type(ParticipantEntitiesInfo)),
                    qos=cyclone_peer.xcdr1_qos(Policy.Reliability.Reliable(duration(seconds=1)),
                                               Policy.Durability.TransientLocal,
                                               Policy.History.KeepLast(100)))
    domain.spawn(["-m", "tests.nodes.listener", "--ros-args", "-r", "__node:=ears",
                  "-r", "__ns:=/robot"])
    domain.spawn(["-m", "udt_node.node"])
    seen: set[str] = set()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not {"/robot/ears", "/udt_node"} <= seen:
        for info in cyclone_peer.take_all(rd, ParticipantEntitiesInfo):
            for node in info.node_entities_info_seq:
                seen.add(f"{node.node_namespace.rstrip('/')}/{node.node_name}")
        time.sleep(0.1)
    assert {"/robot/ears", "/udt_node"} <= seen, seen
