"""One edge serving three devices within one keyframe budget, every node its own process on a
loopback domain: two devices listed, the third found on the graph; each device is tracked and
answered on its own namespace, each map stays within the share the edge granted it, the maps
together never exceed V_total, and a device that vanishes mid-run has its share reclaimed by
the others."""

from __future__ import annotations

import signal
from typing import Any

import pytest
from twinslam_msgs.msg import FrameSummaries, KeyframeBudget, MapStats, UploadRequest

from msg_schemas import qos
from msg_schemas.headers import time_seconds
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.session import RosSession

#: per device: slot length in frames, channel seed, first frame of the synthetic room played.
#: The cameras play at half speed (RATE): slots of 1 s and 1.5 s, as 30 and 45 frames at full
#: speed, on half the frames to render, extract and track (what is tested is the edge's
#: budget over slots and seconds, not the frame count)
DEVICES = {"ar1": (15, 0, 0), "ar2": (15, 1, 200), "ar3": (23, 2, 400)}
RATE, FRAME_RATE_HZ = 0.5, 30.0
#: frames each device may play: 60 slots of 15. The lost device is killed after its third
#: slot once granted its minimum, silent 3 s, then reclaimed RECLAIM_S later — around the
#: twenty-fifth slot of the others on an idle machine, past their thirty-fifth on a loaded
#: one (a joining device waits there for the others' maps to shrink) — and the players of the
#: two that stay are stopped once each has planned AFTER_RECLAIM slots after the reclaim
FRAMES, V_TOTAL, MINIMUM = 900, 24, 5
#: seconds a silent device waits before its share is reclaimed. A clean clone's suite on
#: 2 cores once heard no summary from either staying device for 12.9 s, then a burst (2026-12-01:
#: the edge answered what came; why the devices stalled is not known): with 2 s (5 s of
#: silence in all) the edge reclaimed a device that was still running, and the summaries it
#: sent meanwhile went unanswered. The production default is 60 s.
RECLAIM_S = 15.0
GONE = "ar3"                               #: killed after a few slots
AFTER_RECLAIM = 3                          #: slots each staying device must plan after it

#: the nodes are forked from the launchers' fork server (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


@pytest.mark.slow(seconds=50)
def test_one_edge_serves_three_devices_within_one_budget_and_reclaims_a_lost_ones_share(
        domain: LoopbackDomain, ros: RosSession) -> None:
    got: dict[str, dict[str, list[Any]]] = {d: {"summaries": [], "requests": [], "stats": []}
                                           for d in DEVICES}
    budgets: list[KeyframeBudget] = []
    #: every MapStats and budget as (its stamp, its device or "", the message): the edge
    #: publishes them from its one slot thread, so their stamps order them as the edge made
    #: them. DDS orders no messages across topics, and the executor takes ready subscriptions
    #: in its own order: in arrival order one device's MapStats could be counted beside
    #: another's before that one's shrink (measured: 9 + 9 + 8 against V_total 24, the 8
    #: already freed) or a reclaimed device's map after the budget that released it
    published: list[tuple[float, str, Any]] = []

    def on_stats(device: str, msg: MapStats) -> None:
        got[device]["stats"].append(msg)
        published.append((time_seconds(msg.header.stamp), device, msg))

    sub = ros.node.create_subscription
    for d, rec in got.items():
        sub(FrameSummaries, f"/{d}/device/frame_summaries", rec["summaries"].append,
            qos.PROTOCOL)
        sub(UploadRequest, f"/{d}/edge/upload_request", rec["requests"].append, qos.PROTOCOL)
        sub(MapStats, f"/{d}/edge/map_stats", lambda m, d=d: on_stats(d, m), qos.PROTOCOL)
    stats_at_reclaim: dict[str, int] = {}     # each device's MapStats count when it came

    #: devices the edge published silent (out of the split) while they still ran: a loaded
    #: machine can delay a device's summaries past device_silent_s, and the budget's rule then
    #: takes its share away until the others shrink again
    silenced: set[str] = set()
    running = set(DEVICES)

    def on_budget(msg: KeyframeBudget) -> None:
        budgets.append(msg)
        published.append((time_seconds(msg.header.stamp), "", msg))
        silenced.update(d for d, a in zip(msg.devices, msg.active, strict=True)
                        if not a and d in running)
        served = any(GONE in b.devices for b in budgets)   # before it joined: not a reclaim
        if served and GONE not in msg.devices and not stats_at_reclaim:
            stats_at_reclaim.update({d: len(r["stats"]) for d, r in got.items()})

    sub(KeyframeBudget, "/edge/keyframe_budget", on_budget, qos.PROTOCOL)
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=lff",
                         "-p", "devices:=[ar1, ar2]", "-p", "discover_devices:=true",
                         "-p", f"vmax_total:={V_TOTAL}",
                         "-p", "allocator:=motion", "-p", f"min_keyframes:={MINIMUM}",
                         # silent after two of ar3's 1.5-s slots: with 2 s, a loaded machine's
                         # late summaries flickered devices silent, and the others took the
                         # joining device's share each time (it stayed below its minimum)
                         "-p", "device_silent_s:=3.0", "-p", f"device_reclaim_s:={RECLAIM_S}",
                         "-p", "visualisation:=false"], forks=FORKS)
    assert domain.wait_for_log(edge, "listening on /ar2/device/frame_summaries", 90), \
        domain.log(edge)[-2000:]
    procs = {}
    for d, (slot_frames, seed, start) in DEVICES.items():
        procs[d] = [
            domain.spawn(["-m", "device_tracker.node", "--ros-args", "-r", f"__ns:=/{d}",
                          "-p", f"slot_frames:={slot_frames}", "-p", f"seed:={seed}",
                          "-p", f"frame_rate_hz:={FRAME_RATE_HZ * RATE}",
                          "-p", f"map_frame:={d}/map",
                          # devices that track every frame: what is tested is the edge's budget
                          "-p", "map_source:=edge+local"], forks=FORKS),
            domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args",
                          "-r", f"__ns:=/{d}", "-p", f"sequence:=synthetic:{start + FRAMES}",
                          "-p", f"start:={start}", "-p", "wait_for_subscribers:=1",
                          "-p", f"rate:={RATE}",
                          # the camera waits for its device (a slot's frames unposed at
                          # most): beside the suite's other workers these devices fell 150
                          # frames behind and dropped 6-185 frames each, their summaries
                          # seconds late — the silences the edge then read as a device gone
                          "-p", f"pace_frames:={slot_frames}",
                          "-p", f"frame_id:={d}/camera", "-p", f"map_frame:={d}/map"], forks=FORKS)]
    # the third device goes away once it has been granted its minimum (it joined last and
    # waited for the others' maps to shrink), planned three slots and holds keyframes in the
    # budget's latest split — the share the others then grow into (a loaded machine can
    # delay its summaries until the edge finds it silent and its map empties first): camera
    # and tracker killed
    def gone_holds_keyframes() -> bool:
        last = next((b for b in reversed(budgets) if GONE in b.devices), None)
        if last is None:
            return False
        at = list(last.devices).index(GONE)
        return bool(last.active[at]) and last.map_sizes[at] > 0

    assert ros.spin_until(lambda: len(got[GONE]["stats"]) >= 3 and any(
        s.keyframe_budget >= MINIMUM for s in got[GONE]["stats"]) and gone_holds_keyframes(),
        120.0), (f"{ {d: {k: len(v) for k, v in r.items()} for d, r in got.items()} }; edge: "
                 f"{domain.log_with_stacks(edge)}")
    running.discard(GONE)
    for proc in procs[GONE]:
        proc.send_signal(signal.SIGKILL)
    assert ros.spin_until(lambda: bool(stats_at_reclaim), 60.0), \
        f"{GONE}'s share was not reclaimed: {domain.log(edge)[-2000:]}"
    stayed = [d for d in DEVICES if d != GONE]
    assert ros.spin_until(lambda: all(len(got[d]["stats"]) - stats_at_reclaim[d]
                                      >= AFTER_RECLAIM for d in stayed), 120.0), \
        {d: len(got[d]["stats"]) - stats_at_reclaim[d] for d in stayed}
    running.clear()
    for d in stayed:
        procs[d][1].send_signal(signal.SIGINT)
    assert ros.spin_until(lambda: all(procs[d][1].poll() is not None for d in stayed), 30.0), \
        "the players did not stop"
    # every slot a staying device summarised is answered (its last MapStats may trail)
    assert ros.spin_until(lambda: all(
        {int(m.slot) for m in got[d]["stats"]} >= {int(m.slot) for m in got[d]["summaries"]}
        for d in DEVICES if d != GONE), 30.0), \
        (f"{ {d: (len(r['summaries']), len(r['stats'])) for d, r in got.items()} }; edge: "
         f"{domain.log_with_stacks(edge)}")
    # the edge publishes the budget without the lost device as it reclaims it, and says so in
    # its log a moment later
    assert domain.wait_for_log(edge, f"device {GONE}: silent for", 10.0), domain.log(edge)[-3000:]
    log = domain.log(edge)
    assert "serving device ar3 (its /ar3/device/frame_summaries)" in log, log[-3000:]
    assert "share of the keyframe budget are reclaimed" in log, log[-3000:]
    overfull = overfull_moments(published, V_TOTAL)
    assert not overfull, f"maps held more than V_total together: {overfull[:5]}"
    for d, rec in got.items():
        summaries = rec["summaries"]
        tracked = sum(f.tracked for s in summaries for f in s.frames)
        frames = sum(len(s.frames) for s in summaries)
        assert frames and tracked / frames > 0.8, f"{d}: {tracked}/{frames} frames tracked"
        # answered on its own namespace, slot by slot, for its own frames
        own = {int(s.slot): {f.frame_id for f in s.frames} for s in summaries}
        for req in rec["requests"]:
            assert set(req.upload_frame_ids) <= own[int(req.slot)], d
        for stats in rec["stats"]:
            assert stats.map_size <= stats.keyframe_budget, \
                (d, stats.slot, stats.map_size, stats.keyframe_budget)
            # from the summaries to the map: at least the edge's own work on the slot
            assert stats.slot_latency_ms >= stats.slot_processing_ms > 0, (d, stats.slot)
        # a device joining a full budget waits for the others' maps to shrink at their next
        # slots (a loaded edge: several of its own slots) and grows by what its uploads add;
        # once granted its minimum it keeps it while it is heard (one the edge found silent,
        # its summaries late on a loaded machine, left the split by the budget's rule)
        budgets_of = [int(s.keyframe_budget) for s in rec["stats"]]
        reached = next((k for k, b in enumerate(budgets_of) if b >= MINIMUM), None)
        assert reached is not None, (d, budgets_of)
        assert d in silenced or all(b >= MINIMUM for b in budgets_of[reached:]), \
            (d, budgets_of)
    for b in budgets:
        assert sum(b.map_sizes) <= b.total == V_TOTAL and sum(b.committed) <= V_TOTAL
        assert all(t >= MINIMUM for t, a in zip(b.targets, b.active, strict=True) if a)
    early = next(b for b in budgets if len(b.devices) == 3 and all(b.active))
    assert GONE in early.devices
    # the budgets from the reclaim on, while both staying devices are served (once their
    # players end, each goes silent and is reclaimed in turn: a slow machine ends them apart)
    joined = next(k for k, b in enumerate(budgets) if GONE in b.devices)
    reclaim = next(k for k, b in enumerate(budgets) if k > joined and GONE not in b.devices)
    after = [b for b in budgets[reclaim:] if sorted(b.devices) == stayed]
    assert after, [list(b.devices) for b in budgets[reclaim:]]
    # between them, the two active ones are allotted all of V_total (by their next grants:
    # the budget published at the reclaim still holds the three-way targets, [8, 8])
    both_active = [b for b in after if all(b.active)]
    assert both_active and sum(both_active[-1].targets) == V_TOTAL, \
        [(list(b.targets), list(b.active)) for b in after]
    # the two that stayed grow into the keyframes the lost one held: granted together more
    # than they could have been beside its map (how the split goes between the two is the
    # motion allocator's business; each grant also waits for the uploads that can fill it)
    before = next(b for b in reversed(budgets) if GONE in b.devices)
    held_by_gone = before.committed[list(before.devices).index(GONE)]
    assert max(sum(b.granted) for b in after) > V_TOTAL - held_by_gone, \
        ([list(b.granted) for b in after], held_by_gone)


def overfull_moments(published: list[tuple[float, str, Any]], total: int
                     ) -> list[tuple[str, int, dict[str, int]]]:
    """The moments the devices' published maps held more than ``total`` keyframes together,
    the edge's messages replayed in the order it stamped them: each device's map as its
    latest MapStats said, a device dropped from a budget released (device, slot, sizes)."""
    sizes: dict[str, int] = {}
    over = []
    for _, device, msg in sorted(published, key=lambda p: p[0]):
        if isinstance(msg, KeyframeBudget):
            for gone in set(sizes) - set(msg.devices):
                del sizes[gone]
            continue
        sizes[device] = int(msg.map_size)
        if sum(sizes.values()) > total:
            over.append((device, int(msg.slot), dict(sizes)))
    return over
