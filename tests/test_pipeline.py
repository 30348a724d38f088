"""The live pipeline on a loopback domain: sequence_player → device_tracker ⇄ edge_mapper, every
node its own process, on the first 180 real 7-Scenes frames played at half speed in six slots of
30 frames (2 s each, as 60-frame slots at full speed), or 180 frames of the synthetic room where
the sample is absent (``tests/data_paths.py``).

Per slot the edge asks for exactly ⌊d_k·D_req/α⌋ frames, the map never exceeds V_max, every
upload takes at least its bytes / d_k, the device's ATE stays under 0.15 m, and MapStats.u is
the u(G) of the published map. LFF, PU and ADAPT decide differently and ADAPT's mean υ is
lower than LFF's. An edge killed with SIGKILL mid-run comes back from its checkpoint, its
track table included. Slots shorter than their uploads never leave more than V_max
keyframes, and a device that lost tracking on the way back relocalises against the edge's map.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from msg_schemas.headers import stamp_seconds, time_key
from tests.data_paths import seven_or_synthetic
from tests.paced_runs import PACE_FRAMES, assert_kept_up
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import LaunchConfig, Launcher
from twinslam.live.report import RunReport
from twinslam.live.run_log import RunLog
from twinslam.live.scenarios import SCENARIOS, Scenario
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.keyframe_map import shared_counts
from twinslam.slam.front_end.tracking import TrackingConfig
from twinslam.slot_protocol import default_device
from twinslam.uncertainty.map_uncertainty import map_uncertainty

SEQUENCE = seven_or_synthetic()
#: the bundled parameter file's (the default device's) V_max, α and D_req
FRAMES, VMAX, ALPHA, D_REQ = 180, 45, 5.0, default_device.D_REQ_S
#: the policy runs: slots of 30 frames at half speed last 2 s, as 60-frame slots at full speed
#: do (the uploads a slot asks for follow d_k and D_req, not the frame count), on half the
#: frames to extract and track
SLOT_FRAMES, RATE = 30, 0.5
SLOTS = FRAMES // SLOT_FRAMES
pytestmark = pytest.mark.slow


def reads_the_policy_runs(test: Callable[..., None]) -> Callable[..., None]:
    """A test that reads the three policy runs: one worker makes the runs once for all of them
    (about 70 s), so these tests are handed out among the first."""
    grouped = pytest.mark.xdist_group("pipeline-policy-runs")(test)
    return pytest.mark.slow(seconds=75)(grouped)  # type: ignore[no-any-return]


def _run(policy: str, frames: int = FRAMES, checkpoint: Path | None = None,
         on_stats: Any = None, extra: dict[str, list[str]] | None = None,
         scenario: Scenario = SCENARIOS["forward"], sequence: str = SEQUENCE, rate: float = 1.0,
         pace_frames: int = PACE_FRAMES) -> tuple[RunReport, RunLog, Launcher]:
    """One run of ``frames`` played at ``rate`` × their recorded speed, the camera waiting for
    the device beyond ``pace_frames`` unposed frames (the run fails where the device dropped
    frames all the same); ``extra``: node parameters beside the launch file's. The device is
    the Edge-SLAM style one (the default device's map source, written out) unless ``extra``
    names its map source: what these tests check — the protocol, the edge's restore, its
    planners — needs a device that tracks every frame of the walk, which the paper's device
    does not promise; the tests of the paper's device ask for it by name."""
    device = (extra or {}).get("device_tracker", [])
    if not any(a.startswith("map_source:=") for a in device):
        extra = {**(extra or {}), "device_tracker": [*device, "map_source:=edge+local"]}
    with LoopbackDomain() as dom:
        dom.activate()
        launcher = Launcher(dom, LaunchConfig(sequence, policy, frames, rate,
                                              checkpoint=checkpoint, timeout_s=240.0,
                                              extra=extra or {}, scenario=scenario,
                                              pace_frames=pace_frames),
                            echo=print)
        report = launcher.run(lambda msg, record: on_stats(msg, record, launcher)
                              if on_stats else None)
    assert launcher.record is not None and launcher.record.stats, \
        f"{policy}: the edge published no MapStats"
    assert_kept_up(launcher.logs["device_tracker"])
    return report, launcher.record, launcher


class _Viewer:
    """An outside subscriber to the edge's viewer topics (a viewer's, latched QoS) and the TF
    tree (tf2's QoS), joining after the first slot and spun at every MapStats of the run it
    watches."""

    def __init__(self) -> None:
        self.seen: dict[str, dict[int, Any]] = {"cloud": {}, "poses": {}, "marks": {}, "tf": {},
                                                "tf_static": {}}
        self.session: Any = None

    def __call__(self, _msg: Any, _record: RunLog, _launcher: Launcher) -> None:
        from geometry_msgs.msg import PoseArray
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2
        from visualization_msgs.msg import MarkerArray

        from msg_schemas import topics
        from msg_schemas.headers import stamp_key
        from twinslam.node_runtime.session import RosSession

        if self.session is None:
            self.session = RosSession("viewer")
            latched = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            for key, kind, topic, header in (
                    ("cloud", PointCloud2, topics.MAP_POINTS, lambda m: m.header),
                    ("poses", PoseArray, topics.KEYFRAME_POSES, lambda m: m.header),
                    ("marks", MarkerArray, topics.DECISIONS, lambda m: m.markers[0].header)):
                self.session.node.create_subscription(
                    kind, topic, lambda m, k=key, h=header: self.seen[k].__setitem__(
                        stamp_key(h(m)), m), latched)
            from rclpy.qos import HistoryPolicy
            from tf2_msgs.msg import TFMessage

            from msg_schemas import qos
            deep_tf = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE)
            for key, topic, profile in (("tf", topics.TF, deep_tf),
                                        ("tf_static", topics.TF_STATIC, qos.TF_STATIC)):
                self.session.node.create_subscription(
                    TFMessage, topic, lambda m, k=key: self._transforms(k, m), profile)
        self.session.spin_until(lambda: False, 0.05)

    def _transforms(self, key: str, msg: Any) -> None:
        """stamp → (parent, child) → transform, as a viewer's TF buffer keys them."""
        from msg_schemas.headers import stamp_key

        for t in msg.transforms:
            self.seen[key].setdefault(stamp_key(t.header), {})[
                (t.header.frame_id, t.child_frame_id)] = t

    def close(self) -> None:
        if self.session is not None:
            self.session.spin_until(lambda: False, 1.0)      # the last slot's messages
            self.session.close()


def _policy_run(policy: str, on_stats: Any = None) -> tuple[RunReport, RunLog, Launcher]:
    return _run(policy, on_stats=on_stats, rate=RATE,
                extra={"device_tracker": [f"slot_frames:={SLOT_FRAMES}"]})


@pytest.fixture(scope="module")
def viewed_lff() -> tuple[tuple[RunReport, RunLog, Launcher], dict[str, dict[int, Any]]]:
    """The LFF run, watched by an outside viewer of the edge's viewer topics."""
    viewer = _Viewer()
    try:
        run = _policy_run("lff", on_stats=viewer)
    finally:
        viewer.close()
    return run, viewer.seen


@pytest.fixture(scope="module")
def runs(viewed_lff: tuple) -> dict[str, tuple[RunReport, RunLog, Launcher]]:
    return {"lff": viewed_lff[0], **{p: _policy_run(p) for p in ("pu", "adapt")}}


@reads_the_policy_runs
def test_protocol_holds_every_slot(runs: dict) -> None:
    report, record, _ = runs["adapt"]
    assert report.slots == SLOTS, f"{report.slots} slots answered"
    for slot, summary in record.summaries.items():
        request = record.requests[slot]
        expected = min(math.floor(summary.rate_mbps * D_REQ / ALPHA + 1e-9), len(summary.frames))
        assert len(request.upload_frame_ids) == expected, f"slot {slot}"
        assert set(request.upload_frame_ids) <= {f.frame_id for f in summary.frames}
    for slot, stats in record.stats.items():
        assert stats.map_size <= VMAX, f"slot {slot}: {stats.map_size} keyframes"
    for slot, t in record.throughput.items():
        assert t.frames_sent == len(record.requests[slot].upload_frame_ids)
        # the uplink shaper: every byte took at least 8 / d_k
        assert t.duration_s >= t.bytes_sent * 8 / (t.configured_rate_mbps * 1e6) - 1e-6
        assert t.achieved_mbps <= t.configured_rate_mbps * 1.001
        assert t.bytes_sent >= t.frames_sent * ALPHA * 1e6 / 8
    print(f"\nADAPT: ATE {report.ate_m:.3f} m, {report.frames_uploaded} uploads, "
          f"{report.untracked_frames} untracked frames, edge {report.edge_ms_median:.0f} ms")
    assert report.ate_m < 0.15


@reads_the_policy_runs
def test_the_report_measures_the_downlink_and_the_devices_cpu(runs: dict) -> None:
    """What a user reads beside the tracking: the MB the edge sent down (every map update,
    as serialised), the device's CPU milliseconds a frame from its own summaries, and the
    share of frames it failed."""
    report, record, _ = runs["adapt"]
    assert len(record.maps) >= SLOTS - 1
    # a map update carries at least each point's id, position and descriptor
    floor_mb = sum(len(m.point_ids) * (8 + 24 + 32) for m in record.maps.values()) / 1e6
    assert floor_mb <= report.downlink_mb < 20 * floor_mb, (floor_mb, report.downlink_mb)
    cpu = [f.cpu_ms for s in record.summaries.values() for f in s.frames]
    assert all(c > 0 for c in cpu) and 1.0 < report.device_cpu_ms < 1000.0
    frames = sum(len(s.frames) for s in record.summaries.values())
    assert report.failed_share == pytest.approx(report.untracked_frames / frames)


#: how long after a map update is heard the device may still track frames on the older map
GRACE_S = 1.0


@reads_the_policy_runs
def test_the_update_loop_of_every_answered_slot_is_measured_stage_by_stage(runs: dict) -> None:
    """The monitor hears each slot's summaries, the request they caused and the throughput
    report the request caused — in that order — then the slot's map, and a frame the camera
    captured later is tracked on it: every stage is measured; the uploads take at least what
    the device's report says sending them took."""
    from msg_schemas.headers import time_seconds
    from twinslam.live.update_loop import STAGES, update_loop_latencies

    _, record, _ = runs["adapt"]
    loops = {x.slot: x for x in update_loop_latencies(record)}
    assert sorted(loops) == sorted(record.summaries)
    last_capture = max(time_seconds(f.stamp) for s in record.summaries.values() for f in s.frames)
    for slot, x in loops.items():
        stages = [getattr(x, s) for s in STAGES]
        # a map heard after the run's last frames (the last slot's always; on a loaded machine
        # the one before too: a clean clone's suite heard slot 4's map 3.0 s after the slot's
        # last frame, after the run's) has no frame to be tracked on; one heard with frames
        # still to come must be used by them (GRACE_S: the device decodes it first)
        if not record.heard.get("map", {}).get(slot, math.inf) < last_capture - GRACE_S:
            stages = stages[:-1]
        assert all(math.isfinite(v) for v in stages), (slot, stages)
        # the decision may read zero: a monitor that heard the request before the summaries
        # that caused it counts the summaries as heard with it (update_loop's causal order)
        assert min(x.summaries_s, x.uploads_s) > 0, (slot, stages)
        assert x.uploads_s >= record.throughput[slot].duration_s - 0.05, slot


@reads_the_policy_runs
def test_map_stats_uncertainty_is_the_published_maps(runs: dict) -> None:
    _, record, _ = runs["adapt"]
    checked = 0
    for slot, stats in record.stats.items():
        update = record.maps.get(slot)
        if update is None:
            continue
        assert len(update.keyframe_points) == len(update.keyframe_ids) == stats.map_size
        w = shared_counts([p.astype(np.int64) for p in update.keyframe_points])
        u = map_uncertainty(w, 0.0)
        assert u == pytest.approx(stats.uncertainty, rel=1e-9), f"slot {slot}"
        checked += 1
    assert checked >= SLOTS - 1


@reads_the_policy_runs
def test_policies_decide_differently_and_the_edge_reports_consistent_scores(
        runs: dict) -> None:
    """Each policy asks for its own frames, and every MapStats obeys
    mean = (1 - lost) · tracked (a lost frame scores 0): the edge reports the three
    figures of one slot. Which policy scores best live is not asserted: on 10 slots the
    margins between ADAPT and LFF are a few percent and depend on timing (the simulator's
    tests compare policies; docs/results/paper-device.md has the live evaluation)."""
    uploads = {p: [sorted(r[1].requests[s].upload_frame_ids) for s in sorted(r[1].requests)]
               for p, r in runs.items()}
    assert uploads["lff"] != uploads["adapt"] and uploads["pu"] != uploads["adapt"] \
        and uploads["lff"] != uploads["pu"]
    print(f"\nmean υ: { {p: r[0].mean_uncertainty for p, r in runs.items()} }, tracked: "
          f"{ {p: r[0].tracked_uncertainty for p, r in runs.items()} }, lost: "
          f"{ {p: r[0].lost_share for p, r in runs.items()} }")
    checked = 0
    for policy, (_, record, _) in runs.items():
        for slot, stats in record.stats.items():
            if math.isfinite(stats.tracked_uncertainty):
                assert stats.mean_uncertainty == pytest.approx(
                    (1 - stats.lost_share) * stats.tracked_uncertainty,
                    rel=1e-6), f"{policy} slot {slot}"
                checked += 1
    assert checked >= 3 * (SLOTS - 2)


@pytest.mark.slow(seconds=45)
def test_edge_killed_mid_run_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    state: dict[str, Any] = {}

    def fault(msg: Any, record: RunLog, launcher: Launcher) -> None:
        # MapStats and MapUpdate travel on different topics, and a slot's map often comes
        # after its stats: "before" is the newest map the edge had acknowledged when killed
        slot = int(msg.slot)
        acked = max(record.maps, default=-1)
        if "killed" not in state and slot >= 2 and acked >= 2:
            before = record.maps[acked]
            state["killed"] = (acked, set(before.keyframe_ids.tolist()), before.version)
            launcher.kill("edge_mapper")
            launcher.start("edge_mapper")
        elif "killed" in state and "after" not in state:
            state["after"] = slot            # its map is read once the run is over
            launcher.end_playback()

    def msg_evictions(record: RunLog, slot: int) -> list[int]:
        req = record.requests.get(slot)
        return [int(f) for f in req.evict_frame_ids] if req is not None else []

    # slots of 4 s (30 frames at a quarter speed) until the restarted edge answered one: it
    # takes a few seconds to start, more on a loaded machine, and summaries sent while none
    # listens are lost; at most 20 slots (what is tested is the restore, not real-time
    # tracking). The Edge-SLAM style device tracks on its own points while the edge is down,
    # so the ATE below measures the restore, not the outage
    frames, slot_frames = 600, 30
    report, record, launcher = _run("adapt", frames, tmp_path / "edge.npz", fault, rate=0.25,
                                    extra={"device_tracker": [f"slot_frames:={slot_frames}",
                                                              "map_source:=edge+local"]})
    assert "after" in state, "the restarted edge answered no slot"
    killed_slot, kept, version = state["killed"]
    slot = state["after"]
    after = record.maps[slot]
    kfs, new_version = set(after.keyframe_ids.tolist()), after.version
    # kept unless a decision after that map evicted it
    evicted = {f for k in range(killed_slot + 1, slot + 1) for f in msg_evictions(record, k)}
    assert slot > killed_slot and new_version > version
    assert kept - evicted <= kfs, "a keyframe the edge had acknowledged was lost"
    restored = re.search(r"restored map version .*?(\d+) device tracks resolved",
                         launcher.logs["edge_mapper"])
    assert restored, "the restarted edge did not say what it restored"
    # the device's tracks the edge had resolved survive the kill (tests/test_edge_core.py
    # checks the table itself and that a known track keeps its point)
    assert int(restored.group(1)) > 0, "the track -> map point table was lost"
    assert max(record.stats) == launcher.expected_slots() - 1, "the run did not complete"
    assert report.ate_m < 0.15


def test_slots_shorter_than_their_uploads_never_leave_more_than_vmax() -> None:
    """Slots shorter than their uploads may take, so the edge plans slot k+1 while slot k's
    keyframes are still on the way. Every map the edge publishes holds at most V_max
    keyframes (it grew to 36 of 15 before plans counted the open slots' uploads in).

    A slot lasts as long as its frames take to come in and be tracked: at 30 Hz, 10 frames
    are 0.33 s, but a device beside the suite's other workers tracked 8 frames a second (its
    slots 1.0–1.5 s) and no slot overlapped 0.5 s uploads. So the camera plays at a quarter
    speed, waiting for its device: 10 frames are 1.33 s of wall time however fast the device
    is beyond 7.5 frames a second, and uploads take up to 2.5 s (D_req; a 20 Mbit/s slot's
    ten frames of 5 Mbit fill them, a 40 Mbit/s one's take 1.25 s) — about 1.4 slots of
    uploads a slot, as 0.5 s uploads over 0.33 s slots were."""
    vmax = 15
    report, record, _ = _run("adapt", frames=200, rate=0.25,
                             extra={"device_tracker": ["slot_frames:=10", "rate_min:=20.0",
                                                       "rate_max:=40.0"],
                                    "edge_mapper": [f"vmax:={vmax}", "d_req_s:=2.5"]})
    assert report.frames_dropped == 0, "the device fell behind its camera"
    assert report.slots >= 15 and len(record.stats) >= 15
    sizes = {slot: s.map_size for slot, s in record.stats.items()}
    assert max(sizes.values()) <= vmax, sizes
    assert max(sizes.values()) >= vmax - 2, f"the map never filled: {sizes}"
    # the slots did overlap: some slot was requested before the previous one finished
    overlapped = [k for k in record.stats if k + 1 in record.requests and
                  stamp_seconds(record.requests[k + 1].header)
                  < stamp_seconds(record.stats[k].header)]
    assert overlapped, "no slot overlapped its predecessor: the test tests nothing"


def test_the_edge_plans_with_mpc_in_a_world_of_its_live_map() -> None:
    """``policy:=mpc:H=2`` decides every slot at the edge (from the live map and the
    device's poses, edge_mapper/planning_world.py): Theorem 1's sizes, uploads among the
    slot's frames, evictions once the small map is full, never more than V_max."""
    vmax = 12
    # five slots of 2 s: 30 frames each at half speed
    report, record, _ = _run("mpc:H=2", frames=150, rate=RATE,
                             extra={"edge_mapper": [f"vmax:={vmax}"],
                                    "device_tracker": [f"slot_frames:={SLOT_FRAMES}"]})
    assert report.slots == 150 // SLOT_FRAMES and set(record.requests) == set(record.summaries)
    for slot, summary in record.summaries.items():
        request = record.requests[slot]
        assert request.policy == "mpc:H=2", f"slot {slot} decided by {request.policy}"
        expected = min(math.floor(summary.rate_mbps * D_REQ / ALPHA + 1e-9),
                       sum(f.tracked for f in summary.frames))
        assert len(request.upload_frame_ids) == expected, f"slot {slot}"
        assert set(request.upload_frame_ids) <= {f.frame_id for f in summary.frames if f.tracked}
    assert any(len(r.evict_frame_ids) for r in record.requests.values()), "the map never filled"
    assert all(s.map_size <= vmax for s in record.stats.values())
    # every keyframe the edge integrated is in its map or its archive (500 by default: none
    # forgotten), and MapStats counts the archive
    integrated = np.cumsum([record.stats[k].uploads for k in sorted(record.stats)])
    assert [s.archived_keyframes for _, s in sorted(record.stats.items())] == [
        int(n) - record.stats[k].map_size for n, k in zip(integrated, sorted(record.stats),
                                                          strict=True)]
    assert max(s.archived_keyframes for s in record.stats.values()) > 0


def test_a_device_that_lost_tracking_relocalises_against_the_edges_map() -> None:
    """The synthetic room played forward then backward, the lens covered for 3 s on
    the way back (the camera walks on meanwhile). The device loses tracking once, then
    relocalises — matched by descriptor and solved by PnP RANSAC against its local map, which
    is the edge's last map plus a few own recent points, then tracked through its probation —
    and the report counts both, and no jump. The frame it counts as tracked again observes the
    edge's map points, and its pose is the true one."""
    lost = SCENARIOS["revisit-lost"]
    assert lost.blank_s == 3.0
    # 241 frames: 481 played, 8 full slots; the burst covers played frames 336..425. The
    # Edge-SLAM style device, as the docstring says (the paper's device may lose the map's lag
    # again after its relocalisation: 1 to 12 losses seen on a clean clone). The camera waits
    # for the device (a slot's frames at most unposed): in real time a device that shares two
    # cores with the suite's other live runs fell 150 frames behind its camera at the walk's
    # turn and dropped 120 of them — a second loss that measured the machine
    report, record, _ = _run("adapt", frames=241, scenario=lost, sequence="synthetic:241",
                             extra={"device_tracker": ["map_source:=edge+local"]})
    assert report.frames_dropped == 0, (
        f"the device fell behind its camera and dropped {report.frames_dropped} frames (the "
        f"machine was short of CPU): its losses measure the load; {report}")
    assert report.tracking_failures == 1 and report.relocalisations >= 1, report
    # back after the 3 s blank and the relocalisation's probation (frames at 30 Hz)
    probation_s = TrackingConfig().reloc_probation_frames / 30
    assert report.untracked_frames >= 90 and report.jumps == 0
    assert report.recover_s == pytest.approx(3.0 + probation_s, abs=0.2)
    frames = sorted((f for s in record.summaries.values() for f in s.frames),
                    key=lambda f: f.frame_id)
    first = next(f for f in frames if f.relocalised)
    # the relocalised frame itself, on probation: posed (inliers) but not counted tracked
    lost_at = next(i for i, f in enumerate(frames) if not f.tracked and i > 0)
    reloc = next(f for f in frames[lost_at:] if f.inliers > 0 and not f.tracked)
    assert reloc.frame_id < first.frame_id and reloc.inliers >= TrackingConfig().reloc_min_inliers
    assert len(reloc.map_point_ids) >= 50 and len(reloc.map_point_ids) > 10 * len(
        reloc.local_track_ids), "relocalised against the device's own points, not the map"
    assert len(first.map_point_ids) >= 50
    # its pose against the truth, both relative to the first frame (the device's origin)
    truth = record.ground_truth
    origin = truth[min(truth)]
    key = first.stamp.sec * 10**9 + first.stamp.nanosec
    expected = np.linalg.inv(origin) @ truth[key]
    error = np.linalg.norm(record.poses[key][:3, 3] - expected[:3, 3])
    # the run's picture marks it where the device put it (twinslam.live.run_picture)
    from twinslam.live.run_picture import relocalised_positions
    marked = relocalised_positions(record)
    assert len(marked) == report.relocalisations
    assert np.allclose(marked[0], record.poses[key][:3, 3])
    print(f"\nrelocalised frame {first.frame_id}: {len(first.map_point_ids)} map points, "
          f"position error {error * 100:.1f} cm; {report.row()}")
    assert error < 0.05


def came_back(maps: list[set[int]]) -> set[int]:
    """Keyframes that were in a map, missing from a later one and in a map later still."""
    return {kf for i, first in enumerate(maps) for j in range(i + 1, len(maps))
            for kf in first - maps[j] if any(kf in m for m in maps[j + 1:])}


def test_came_back_needs_a_gap() -> None:
    """A keyframe kept from its first map on, or added late, did not come back."""
    assert came_back([{1}, {1, 2}, {1, 2, 3}]) == set()
    assert came_back([{1, 2}, {2}, {1, 2}, {3}]) == {1}


def test_an_evicted_keyframe_comes_back_from_the_archive_on_the_way_back(tmp_path: Path) -> None:
    """The synthetic room forward then back with the paper's device (it tracks against the
    edge's map only) and a map of 8 keyframes: the keyframes evicted on the way out stay in
    the edge's archive (MapStats counts them), and on the way back the edge restores some of
    them where the camera is heading — a keyframe the device's map lost comes back into it —
    and the device tracks the way back. The edge's keyframe trajectory holds the archived
    keyframes too, each at the capture stamp of the frame it was."""
    # 91 frames: 181 played in 6 slots of 30 frames at a quarter speed: one slot restores (the
    # 5th: the camera heads back past the evicted keyframes), on a margin of ~2.4x against the
    # 2x it needs, and once in a full-suite run at half speed it restored nothing (cause not
    # found: dropped frames stretch the heading's speed and shorten its horizon alike)
    report, record, launcher = _run(
        "lff", frames=91, scenario=SCENARIOS["revisit"], sequence="synthetic:91",
        rate=RATE / 2,
        extra={"edge_mapper": ["vmax:=8", "restore_keyframes:=3", "trajectory_every:=1"],
               "device_tracker": [f"slot_frames:={SLOT_FRAMES}", "map_source:=edge"]})
    maps = [set(record.maps[k].keyframe_ids.tolist()) for k in sorted(record.maps)]
    back = sorted(came_back(maps))
    log = launcher.logs["edge_mapper"]
    seen = {k: len(s.frames) for k, s in sorted(record.summaries.items())}
    assert back, f"no keyframe came back into the device's map: {maps}; frames a slot {seen}"
    assert "restored from the archive" in log, f"frames a slot {seen}; {log[-3000:]}"
    assert max(s.archived_keyframes for s in record.stats.values()) > 0
    assert all(s.map_size <= 8 for s in record.stats.values())
    stamps = {time_key(f.stamp): int(f.frame_id) for s in record.summaries.values()
              for f in s.frames}
    trajectory = {stamps[s] for s in record.keyframe_trajectory}     # a KeyError: no frame's
    (sent_with,) = [k for k, t in record.map_stamps.items() if t == record.trajectory_stamp]
    in_map = set(record.maps[sent_with].keyframe_ids.tolist())
    assert in_map < trajectory, (sorted(trajectory), sorted(in_map))
    # MapStats counts what came back, and the run's row and picture show it
    assert report.restores == sum(s.restored_keyframes for s in record.stats.values()) \
        >= len(back)
    from twinslam.live.run_picture import plot_run
    plot_run(record, "restores", tmp_path / "restores.png")
    assert (tmp_path / "restores.png").stat().st_size > 30_000
    print(f"\ncame back: {back}; {report.row()}")
    assert report.untracked_frames < 0.1 * 181, report.row()


@reads_the_policy_runs
def test_a_viewer_sees_the_edges_map_points_keyframes_and_decisions(viewed_lff: tuple) -> None:
    """What RViz or Foxglove would subscribe to: every slot the edge's map as a PointCloud2
    with one point per map point, the kept keyframes as a PoseArray (at most V_max), and the
    slot's decisions as markers — integrated keyframes as many as MapStats counts uploads,
    kept ones the rest of the map — read by a subscriber outside the pipeline that joined
    after the first slot (the topics are latched)."""
    from sensor_msgs.msg import PointField
    from visualization_msgs.msg import Marker

    from msg_schemas.headers import stamp_key

    (_, record, _), seen = viewed_lff
    stats = {stamp_key(s.header): s for s in record.stats.values()}
    slots = [k for k in stats if all(k in seen[by] for by in ("cloud", "poses", "marks"))]
    assert len(slots) >= 3, f"the viewer saw {len(slots)} of {len(stats)} slots"
    for key in slots:
        s, cloud, poses, marks = (stats[key], seen["cloud"][key], seen["poses"][key],
                                  seen["marks"][key])
        assert cloud.header.frame_id == poses.header.frame_id == "map"
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
        assert [(f.offset, f.datatype) for f in cloud.fields] == [
            (4 * i, PointField.FLOAT32) for i in range(4)] and cloud.point_step == 16
        xyzi = np.frombuffer(bytes(cloud.data), dtype=np.float32).reshape(-1, 4)
        assert len(xyzi) == cloud.width == s.map_points
        assert np.isfinite(xyzi).all() and (xyzi[:, 3] >= 1).all()    # observed by >= 1
        assert len(poses.poses) == s.map_size <= VMAX
        by_ns = {m.ns: m for m in marks.markers}
        assert set(by_ns) == {"integrated", "evicted", "restored", "kept"}
        added, restored, kept = (len(by_ns[ns].points) if by_ns[ns].action == Marker.ADD else 0
                                 for ns in ("integrated", "restored", "kept"))
        assert added == s.uploads and restored == s.restored_keyframes
        assert added + restored + kept == s.map_size


@reads_the_policy_runs
def test_a_viewer_follows_the_device_on_the_tf_tree(viewed_lff: tuple) -> None:
    """The TF tree a viewer follows (REP 105): map → odom → camera on /tf at every frame the
    device tracked (their product is its pose on device/pose, stamped alike) and none at a
    frame it did not; world → map on /tf_static (latched: the viewer joined after it went
    out) at the first played frame's ground truth, where the device's map frame starts."""
    from msg_schemas.poses import pose_matrix, pose_msg
    from msg_schemas.transforms import transform_matrix

    (_, record, _), seen = viewed_lff
    tf = seen["tf"]
    assert len(tf) >= 60, f"the viewer saw {len(tf)} transforms on /tf"
    tracked = {time_key(f.stamp): bool(f.tracked) for s in record.summaries.values()
               for f in s.frames}
    first, last = min(tf), max(tf)
    window = {k for k, ok in tracked.items() if ok and first <= k <= last}
    assert set(tf) <= window | {k for k in tf if k > max(tracked)}, \
        "a transform at a frame the device did not track"
    assert len(window - set(tf)) <= 0.02 * len(window), "tracked frames missing on /tf"
    for key, transforms in tf.items():
        assert set(transforms) == {("map", "odom"), ("odom", "camera")}
        np.testing.assert_allclose(transform_matrix(transforms["map", "odom"])
                                   @ transform_matrix(transforms["odom", "camera"]),
                                   record.poses[key], atol=1e-6)
    (statics,) = seen["tf_static"].values()
    (anchor,) = statics.values()
    assert (anchor.header.frame_id, anchor.child_frame_id) == ("world", "map")
    # the sequence's own first frame (the monitor may have missed the first ground truth), as
    # a pose message carries it (the dataset's float32 rotation made orthonormal)
    first_frame = next(iter(open_sequence(SEQUENCE, 0, 1)))
    assert first_frame.pose is not None
    np.testing.assert_allclose(transform_matrix(anchor),
                               pose_matrix(pose_msg(first_frame.pose)), atol=1e-6)


@reads_the_policy_runs
def test_the_picture_of_a_run_shows_its_map_trajectories_and_slots(
        runs: dict, tmp_path: Path) -> None:
    """One PNG a run: written, the size it is drawn at, and not blank — the map's points,
    the trajectories and four per-slot curves put thousands of non-white pixels on it."""
    from matplotlib.image import imread

    from twinslam.live.run_picture import plot_run

    _, record, _ = runs["adapt"]
    path = tmp_path / "adapt.png"
    plot_run(record, "adapt on the sample", path)
    image = imread(path)
    assert image.shape[:2] == (650, 1300)
    assert (image[:, :, :3] < 0.9).any(axis=2).sum() > 20_000
