"""Two device/edge pairs on one ROS domain, moved apart by namespaces only (``-r __ns:=/ar1``,
``-r __ns:=/ar2``): each edge plans, integrates and maps only its own device's frames."""

from __future__ import annotations

from collections import Counter

import pytest
from twinslam_msgs.msg import FrameSummaries, MapStats, MapUpdate, UplinkThroughput, UploadRequest

from msg_schemas import qos
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.session import RosSession

#: per pair: slot length (different, so a frame id tells whose slot it is), channel seed,
#: first frame of the synthetic room played (different views)
PAIRS = {"/ar1": (30, 0, 0), "/ar2": (45, 1, 300)}
#: three slots of ar1's, two of ar2's: enough to tell whose decision answered which slot
FRAMES = 90

#: the nodes are forked from the launchers' fork server (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


@pytest.mark.slow(seconds=20)
def test_two_pairs_share_a_domain_without_cross_talk(domain: LoopbackDomain,
                                                     ros: RosSession) -> None:
    got: dict[str, dict[str, list]] = {}
    for ns in PAIRS:
        rec = got[ns] = {"summaries": [], "requests": [], "stats": [], "throughput": [],
                         "maps": []}
        sub = ros.node.create_subscription
        sub(FrameSummaries, f"{ns}/device/frame_summaries", rec["summaries"].append,
            qos.PROTOCOL)
        sub(UploadRequest, f"{ns}/edge/upload_request", rec["requests"].append, qos.PROTOCOL)
        sub(MapStats, f"{ns}/edge/map_stats", rec["stats"].append, qos.PROTOCOL)
        sub(UplinkThroughput, f"{ns}/device/uplink_throughput", rec["throughput"].append,
            qos.PROTOCOL)
        sub(MapUpdate, f"{ns}/edge/map_update", rec["maps"].append, qos.MAP)
    edges = {ns: domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-r", f"__ns:={ns}",
                               "-p", "policy:=lff", "-p", "vmax:=6"], forks=FORKS) for ns in PAIRS}
    assert all(domain.wait_for_log(e, "listening on", 90) for e in edges.values())
    for ns, (slot_frames, seed, start) in PAIRS.items():
        domain.spawn(["-m", "device_tracker.node", "--ros-args", "-r", f"__ns:={ns}",
                      "-p", f"slot_frames:={slot_frames}", "-p", f"seed:={seed}",
                      # devices that track every frame: what is tested is the isolation
                      "-p", "map_source:=edge+local"], forks=FORKS)
        domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args", "-r", f"__ns:={ns}",
                      "-p", f"sequence:=synthetic:{start + FRAMES}", "-p", f"start:={start}",
                      "-p", "wait_for_subscribers:=1"], forks=FORKS)
    slots = {ns: FRAMES // f for ns, (f, _, _) in PAIRS.items()}

    def every_slot_reported() -> bool:
        # a slot's MapStats can arrive before the device's UplinkThroughput of the same slot
        return all(len(got[ns]["stats"]) >= slots[ns]
                   and {int(t.slot) for t in got[ns]["throughput"]} >= set(range(slots[ns]))
                   for ns in PAIRS)

    assert ros.spin_until(every_slot_reported, 180.0), {
        ns: (len(r["stats"]), len(r["throughput"])) for ns, r in got.items()}
    for ns, rec in got.items():
        slot_frames = PAIRS[ns][0]
        summaries = {int(m.slot): m for m in rec["summaries"]}
        assert sorted(summaries) == list(range(slots[ns]))
        # one decision per slot, for this device's frames at this device's rate
        assert Counter(int(r.slot) for r in rec["requests"]) == Counter(range(slots[ns]))
        for req in rec["requests"]:
            own = summaries[int(req.slot)]
            assert req.rate_mbps == own.rate_mbps, ns
            assert {f.frame_id for f in own.frames} == set(
                range(req.slot * slot_frames, (req.slot + 1) * slot_frames))
            assert set(req.upload_frame_ids) <= {f.frame_id for f in own.frames}, ns
        sent = {int(t.slot): int(t.frames_sent) for t in rec["throughput"]}
        for stats in rec["stats"]:
            assert stats.uploads == sent[int(stats.slot)], (ns, stats.slot)
        requested = {int(f) for r in rec["requests"] for f in r.upload_frame_ids}
        assert set(rec["maps"][-1].keyframe_ids) <= requested, ns
