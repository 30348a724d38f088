"""A standby edge takes over a device whose edge stopped answering, from the checkpoint the
dead edge wrote, and leaves alone a device whose edge answers: the slot count that decides,
and two edge processes and a device on a loopback domain, one edge killed."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest
from twinslam_msgs.msg import MapUpdate

from edge_mapper.edge_failover import UnansweredSlots
from msg_schemas import qos
from tests.paced_runs import PACE_FRAMES, assert_kept_up
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.session import RosSession

#: the nodes are forked from the launchers' fork server (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


def test_a_device_is_due_once_its_slots_go_unanswered() -> None:
    """Slots answered as they come, or one late answer, are no reason; three summaries in a
    row with no answer are. An answer to the newest slot clears what came before it."""
    watch = UnansweredSlots(3)
    for slot in range(5):
        watch.summaries(slot)
        watch.answered(slot)
    assert not watch.due
    watch.summaries(5)
    watch.summaries(6)
    watch.answered(6)                        # slot 5's answer came late, with slot 6's
    assert not watch.due and not watch.unanswered
    for slot in (7, 8):
        watch.summaries(slot)
    assert not watch.due
    watch.summaries(9)
    assert watch.due and watch.unanswered == {7, 8, 9}
    never = UnansweredSlots(2)               # a device no edge ever answered
    never.summaries(0)
    never.summaries(1)
    assert never.due


@pytest.mark.slow(seconds=40)
def test_a_standby_edge_serves_a_device_whose_edge_was_killed(
        domain: LoopbackDomain, ros: RosSession, tmp_path: Path) -> None:
    """The device's edge serves it, the standby only watches; the edge is killed (no goodbye
    to DDS) and within a few slots the standby serves the device from the map the dead edge
    checkpointed: its map versions go on from where the dead edge's stopped. Both edges
    write their checkpoints on a writer thread (``checkpoint_in_background``, as an edge of
    many devices would): the file the standby reads may be a slot behind the device's map,
    and the standby goes on from the version the device holds."""
    maps: list[MapUpdate] = []
    ros.node.create_subscription(MapUpdate, "/ar1/edge/map_update", maps.append, qos.MAP)
    checkpoint = ["-p", f"checkpoint:={tmp_path / 'edge.npz'}", "-p", "visualisation:=false",
                  "-p", "policy:=lff", "-p", "checkpoint_in_background:=true"]
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "devices:=[ar1]",
                         *checkpoint], forks=FORKS)
    standby = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-r",
                            "__node:=edge_standby", "-p", "standby:=true", *checkpoint],
                           forks=FORKS)
    assert domain.wait_for_log(edge, "listening on /ar1/device/frame_summaries", 90)
    device = domain.spawn(["-m", "device_tracker.node", "--ros-args", "-r", "__ns:=/ar1",
                           "-p", "frame_rate_hz:=15.0", "-p", "map_frame:=ar1/map"],
                          forks=FORKS)
    # the camera waits for its device (a slot's frames unposed at most): while the standby
    # restored the map, the device beside the suite's other workers fell 150 frames behind
    # its camera and dropped 66, and tracking was lost over the gap
    domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args", "-r", "__ns:=/ar1",
                  "-p", "sequence:=synthetic:900", "-p", "wait_for_subscribers:=1",
                  "-p", "rate:=0.5", "-p", "frame_id:=ar1/camera", "-p", "map_frame:=ar1/map",
                  "-p", f"pace_frames:={PACE_FRAMES}"], forks=FORKS)
    assert ros.spin_until(lambda: len(maps) >= 4, 90.0), domain.log(edge)[-2000:]
    assert domain.wait_for_log(standby, "standing by for device ar1", 10.0), \
        domain.log(standby)[-2000:]
    assert "taking it over" not in domain.log(standby)
    edge.send_signal(signal.SIGKILL)
    edge.wait(timeout=10)
    before = max(int(s.map_version) for s in maps)
    heard = len(maps)
    # the standby's first update is the dead edge's last map, restored; its next is newer
    assert ros.spin_until(lambda: any(int(m.map_version) > before for m in maps[heard:]),
                          60.0), domain.log(standby)[-3000:]
    log = domain.log(standby)
    assert "device ar1:" in log and "taking it over" in log, log[-3000:]
    assert "restored map version" in log, log[-3000:]
    after = [int(m.map_version) for m in maps[heard:]]
    assert min(after) >= before - 1, (before, after)     # resumed, not started afresh
    assert_kept_up(domain.log(device))
