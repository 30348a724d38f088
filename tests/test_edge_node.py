"""edge_mapper as its own process: frame summaries in, upload requests out, keyframes in, map
updates and stats out; a corrupt keyframe is dropped; SIGKILL and restart resume from the
checkpoint; a slot whose device sent fewer than asked closes at once and counts the rest."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    MapUpdate,
    UplinkThroughput,
    UploadRequest,
)

from device_tracker.messages import (
    FrameRecord,
    frame_summaries_message,
    keyframe_message,
    uplink_throughput_message,
)
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.place_membership import FOLLOWED, PlaceMembership
from msg_schemas import qos, topics
from tests.test_edge_core import Device, K
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.matched_readers import WRITERS, matched_line
from twinslam.node_runtime.session import RosSession
from twinslam.policies.registry import make_policy
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload
from twinslam.uplink.shaper import SlotThroughput

F = 8

#: node processes forked as the launchers fork theirs (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()
#: the edge's log line once its summaries reader matched this test's one writer
#: (twinslam.node_runtime.matched_readers)
SUMMARIES_MATCHED = matched_line(topics.FRAME_SUMMARIES, 1, WRITERS)


def _summaries(device: Device, slot: int, rate: float) -> object:
    frames = [FrameRecord(f, 0.1 * f, device.pose(f), True, np.zeros(0, np.uint64),
                          np.array([int(TRACK_ID_BIT) | int(j) for j in device.observe_ids(f)],
                                   dtype=np.uint64), slot)
              for f in range(slot * F, (slot + 1) * F)]
    return frame_summaries_message(slot, rate, int(rate > 50), 0, frames, time.time())


def _keyframe(device: Device, frame: int, slot: int) -> object:
    seen, uv, depth = device.features(frame)
    return keyframe_message(KeyFramePayload(
        frame, slot, 0.1 * frame, device.pose(frame), K, uv, depth, device.descs[seen],
        np.array([int(TRACK_ID_BIT) | int(j) for j in seen], np.uint64)))


class TrackIdDevice(Device):
    """The simulated device of test_edge_core, reporting new features by track id only (the
    edge associates them by projection)."""

    def features(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cw = np.linalg.inv(self.pose(frame))
        cam = self.world @ cw[:3, :3].T + cw[:3, 3]
        uv = cam[:, :2] / cam[:, 2:] * 500 + [320, 240]
        seen = np.flatnonzero((uv[:, 0] > 5) & (uv[:, 0] < 635) & (uv[:, 1] > 5)
                              & (uv[:, 1] < 475))
        return seen, uv[seen] + self.rng.normal(0, 0.3, (len(seen), 2)), cam[seen, 2]

    def observe_ids(self, frame: int) -> np.ndarray:
        return self.features(frame)[0]


def test_edge_node_protocol_corrupt_keyframe_and_restart(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession) -> None:
    device = TrackIdDevice(np.random.default_rng(0))
    node = ros.node
    pub_sum = node.create_publisher(FrameSummaries, topics.FRAME_SUMMARIES, qos.PROTOCOL)
    pub_kf = node.create_publisher(Keyframe, topics.KEYFRAMES, qos.PROTOCOL)
    pub_sent = node.create_publisher(UplinkThroughput, topics.UPLINK_THROUGHPUT, qos.PROTOCOL)
    got: dict[str, list] = {"request": [], "map": [], "stats": []}
    node.create_subscription(UploadRequest, topics.UPLOAD_REQUEST, got["request"].append,
                             qos.PROTOCOL)
    node.create_subscription(MapUpdate, topics.MAP_UPDATE, got["map"].append, qos.MAP)
    node.create_subscription(MapStats, topics.MAP_STATS, got["stats"].append, qos.PROTOCOL)
    ckpt = tmp_path / "edge.npz"
    args = ["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=lff", "-p", "vmax:=10",
            "-p", f"checkpoint:={ckpt}", "-p", "ba_window:=6", "-p", "d_req_s:=0.5",
            "-p", "restore_keyframes:=0"]

    def run_slot(slot: int, rate: float, withheld: int = 0) -> None:
        """One slot's summaries and the keyframes asked for, ``withheld`` of them not sent
        (the device's throughput report says so)."""
        n_req, n_map = len(got["request"]), len(got["map"])
        pub_sum.publish(_summaries(device, slot, rate))
        assert ros.spin_until(lambda: len(got["request"]) > n_req, 30.0), f"slot {slot}"
        req = got["request"][-1]
        assert req.slot == slot and len(req.upload_frame_ids) == int(rate * 0.5 / 5.0)
        if slot == 1:                                   # a corrupt keyframe: 3 keypoints,
            bad = _keyframe(device, int(req.upload_frame_ids[0]), slot)   # 2 descriptors
            bad.keypoints_xy = np.zeros(6, np.float32)
            bad.descriptors = np.zeros(64, np.uint8)
            pub_kf.publish(bad)
        sent = list(req.upload_frame_ids)[:len(req.upload_frame_ids) - withheld]
        for f in sent:
            pub_kf.publish(_keyframe(device, int(f), slot))
        if withheld:
            pub_sent.publish(uplink_throughput_message(
                SlotThroughput(slot, rate, int(rate > 50), 0, 0.5, len(sent)), time.time()))
        assert ros.spin_until(lambda: len(got["map"]) > n_map and got["map"][-1].slot == slot,
                              60.0), f"no map update for slot {slot}"

    edge = domain.spawn(args, forks=FORKS)
    assert ros.spin_until(lambda: pub_sum.get_subscription_count() > 0
                          and pub_kf.get_subscription_count() > 0, 30.0)
    assert ros.spin_until(lambda: SUMMARIES_MATCHED in domain.log(edge), 30.0)
    for slot, rate in enumerate([40.0, 80.0, 60.0]):
        run_slot(slot, rate)
    assert [m.map_version for m in got["map"]] == [1, 2, 3]
    assert ros.spin_until(lambda: len(got["stats"]) >= 3, 10.0)
    assert all(s.map_size <= 10 for s in got["stats"])
    assert got["stats"][-1].map_size == 10 and np.isfinite(got["stats"][-1].uncertainty)
    assert got["stats"][-1].uploads == 6
    # a running edge on policy:=lff has not loaded torch (tests/test_layers.py: the imports)
    assert "libtorch" not in Path(f"/proc/{edge.pid}/maps").read_text()

    def summary_readers() -> set[bytes]:
        return {bytes(i.endpoint_gid) for i in
                node.get_subscriptions_info_by_topic(f"/{topics.FRAME_SUMMARIES}")}

    archived = got["stats"][-1].archived_keyframes     # evicted, kept in the edge's archive
    assert archived > 0
    killed_readers = summary_readers()
    edge.send_signal(signal.SIGKILL)                                    # the edge host dies
    edge.wait(timeout=10)
    _, _, err_before = domain.stop(edge)
    assert "dropped a malformed twinslam_msgs/msg/Keyframe" in err_before
    last = got["map"][-1]
    edge = domain.spawn(args, forks=FORKS)                              # ... and comes back
    assert ros.spin_until(lambda: len(got["map"]) > 3, 30.0), "no latched map after restart"
    restored = got["map"][-1]
    assert restored.map_version == 3 and list(restored.keyframe_ids) == list(last.keyframe_ids)
    # the new edge's summaries reader is known here (the killed one's may linger until its
    # lease ends) and has matched this writer (it says so: a volatile reader that matches
    # after a sample was written never gets it — knowing the reader was not enough, a clean
    # clone waited 30 s for slot 3's request): a summary published now reaches it
    assert ros.spin_until(lambda: bool(summary_readers() - killed_readers)
                          and SUMMARIES_MATCHED in domain.log(edge), 30.0)
    run_slot(3, 40.0)
    assert got["map"][-1].map_version == 4
    # the device no longer held one of slot 4's frames: the slot closes on its report (not
    # after slot_timeout_s) and MapStats accounts for every upload asked for
    run_slot(4, 60.0, withheld=1)
    assert ros.spin_until(lambda: got["stats"][-1].slot == 4, 10.0)
    stats = got["stats"][-1]
    assert (stats.uploads, stats.refused_keyframes, stats.missing_keyframes) == (5, 0, 1)
    code, _, err = domain.stop(edge)
    assert code == 0, err
    assert "restored map version 3" in err
    # the archive came back with the map, and MapStats counts it on
    assert f"{archived} archived keyframes" in err
    assert got["stats"][-1].archived_keyframes >= archived


def test_an_unreadable_checkpoint_keeps_its_device_unserved_and_the_others_served(
        tmp_path: Path, domain: LoopbackDomain) -> None:
    """One device's checkpoint cannot be read (a disk fault, a file from elsewhere), another's
    map can but the place it records contradicts itself: an edge serving several devices
    serves the others, names each device and why, and leaves the files as they are; an edge
    whose one device it is does not start, and says why."""
    checkpoint = tmp_path / "edge.npz"
    unreadable = tmp_path / "edge.ar2.npz"
    unreadable.write_bytes(b"not a checkpoint")
    placed = tmp_path / "edge.ar3.npz"
    core = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(), placed)
    core.map.add_keyframe(0, np.eye(4))
    record = PlaceMembership("ar1", {"ar1": 5, "ar4": 2}).arrays()
    record[FOLLOWED] = record[FOLLOWED][:1]            # two lenders, one loop count
    core.saved_with = lambda: record
    core.save_checkpoint()
    core.close()
    written = placed.read_bytes()
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args",
                         "-p", "devices:=[ar1, ar2, ar3]", "-p", "merge_maps:=true",
                         "-p", f"checkpoint:={checkpoint}"], forks=FORKS)
    for device in ("ar2", "ar3"):
        assert domain.wait_for_log(edge, f"device {device}: not served, its checkpoint cannot "
                                   "be read", 60.0), domain.log(edge)[-2000:]
    log = domain.log(edge)
    assert "serving device ar1" in log and str(unreadable) in log and "2 lenders" in log
    assert edge.poll() is None, log[-2000:]
    code, _, err = domain.stop(edge)
    assert code == 0, err
    assert unreadable.read_bytes() == b"not a checkpoint" and placed.read_bytes() == written
    alone = domain.spawn(["-m", "edge_mapper.node", "--ros-args",
                          "-p", f"checkpoint:={unreadable}"], forks=FORKS)
    assert alone.wait(timeout=60) != 0
    assert "not a readable map checkpoint" in domain.log(alone), domain.log(alone)[-2000:]
    assert unreadable.read_bytes() == b"not a checkpoint"


def test_a_device_that_starts_again_is_served_with_a_new_map(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession) -> None:
    """A device that restarts (its app, its computer) counts its slots and frame ids from 0
    again while the edge runs on. Planned against the old map, the new run's frames clashed
    with the old run's keyframes ("frames […] are already keyframes", every slot refused) or
    entered a map in a frame the new run never saw. The edge takes a slot it planned and
    closed already for a restart: the old map is set aside as a reclaimed device's and the
    new run gets a map of its own from its next slot."""
    node = ros.node
    pub_sum = node.create_publisher(FrameSummaries, topics.FRAME_SUMMARIES, qos.PROTOCOL)
    pub_kf = node.create_publisher(Keyframe, topics.KEYFRAMES, qos.PROTOCOL)
    got: dict[str, list] = {"request": [], "map": []}
    node.create_subscription(UploadRequest, topics.UPLOAD_REQUEST, got["request"].append,
                             qos.PROTOCOL)
    node.create_subscription(MapUpdate, topics.MAP_UPDATE, got["map"].append, qos.MAP)
    ckpt = tmp_path / "edge.npz"
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=lff",
                         "-p", "vmax:=10", "-p", f"checkpoint:={ckpt}"], forks=FORKS)

    def readers() -> set[bytes]:
        return {bytes(i.endpoint_gid) for i in
                node.get_subscriptions_info_by_topic(f"/{topics.FRAME_SUMMARIES}")}

    def run_slot(device: TrackIdDevice, slot: int) -> MapUpdate:
        n_req, n_map = len(got["request"]), len(got["map"])
        pub_sum.publish(_summaries(device, slot, 40.0))
        assert ros.spin_until(lambda: len(got["request"]) > n_req, 30.0), \
            f"slot {slot}: {domain.log(edge)[-2000:]}"
        req = got["request"][-1]
        assert req.slot == slot
        for frame in req.upload_frame_ids:
            pub_kf.publish(_keyframe(device, int(frame), slot))
        assert ros.spin_until(lambda: len(got["map"]) > n_map and got["map"][-1].slot == slot,
                              60.0), f"no map update for slot {slot}: {domain.log(edge)[-2000:]}"
        return got["map"][-1]

    assert ros.spin_until(lambda: pub_sum.get_subscription_count() > 0
                          and pub_kf.get_subscription_count() > 0
                          and SUMMARIES_MATCHED in domain.log(edge), 30.0)
    first = TrackIdDevice(np.random.default_rng(0))
    for slot in range(3):
        before = run_slot(first, slot)
    assert before.map_version == 3 and len(before.keyframe_ids) > 0
    # one stray message with an old slot is no restart: the walk goes on in its map
    pub_sum.publish(_summaries(first, 1, 40.0))
    assert domain.wait_for_log(edge, "slot 1: summaries of a slot this edge closed", 30.0)
    assert run_slot(first, 3).map_version == 4
    old_readers = readers()
    # the device starts again: slot 0 and frame ids from 0, another walk; its next slot
    # confirms it
    again = TrackIdDevice(np.random.default_rng(1))
    pub_sum.publish(_summaries(again, 0, 40.0))
    pub_sum.publish(_summaries(again, 1, 40.0))
    assert domain.wait_for_log(edge, "started again", 30.0), domain.log(edge)[-2000:]
    # the new run's link listens on a reader of its own: known here, and matched to this
    # writer there (its own "1 writer(s) matched", the second line of it)
    assert ros.spin_until(lambda: bool(readers() - old_readers)
                          and domain.log(edge).count(SUMMARIES_MATCHED) >= 2, 30.0)
    after = run_slot(again, 2)
    log = domain.log(edge)
    assert "cannot plan" not in log, log[-2000:]
    assert "its slot 0 came after this edge had planned slot 3" in log, log[-2000:]
    # a map of its own: the new run's keyframes only, its versions on from the device's
    assert set(after.keyframe_ids) <= set(range(2 * F, 3 * F)) and len(after.keyframe_ids) > 0
    assert Path(f"{ckpt}.reclaimed").is_file()       # the old run's map, set aside
    code, _, err = domain.stop(edge)
    assert code == 0, err
