"""The edge's load on /diagnostics: OK while it keeps up within its budget; WARN, saying why,
while the budget trims its work or a map came later than its slot; the figures a user reads
(slots, latency, slot work, each thread's share of a core) as the status's values."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus

from edge_mapper.load_diagnostics import EdgeLoad, load_status


def _values(load: EdgeLoad) -> tuple[DiagnosticStatus, dict[str, str]]:
    msg = load_status("/edge_mapper", "edgehost", load, 12.5)
    assert len(msg.status) == 1 and msg.header.stamp.sec == 12
    status = msg.status[0]
    assert status.name == "/edge_mapper: load" and status.hardware_id == "edgehost"
    return status, {kv.key: kv.value for kv in status.values}


def test_an_edge_that_keeps_up_within_its_budget_is_ok_and_says_what_it_did() -> None:
    status, values = _values(EdgeLoad(
        devices=3, answered=[(0.3, 1.0), (0.5, 1.0), (0.4, 1.0)], load=0.42, budget=0.6,
        level="bundle adjustment of 5 keyframes, 120 points", trimmed=False,
        threads={"main": 0.41, "loop-closer_0": 0.08, "dds.udp.7001": 0.002,
                 "dds.ev.0": 0.004}))
    assert status.level == DiagnosticStatus.OK
    assert status.message == ("3 devices, 3 slots answered, slot work 42% of a core of a "
                              "budget of 60%")
    assert values["slots_late"] == "0" and values["latency_ms_median"] == "400"
    assert values["latency_ms_max"] == "500" and values["slot_work_cores"] == "0.420"
    assert values["cores main"] == "0.410" and values["cores loop-closer_0"] == "0.080"
    # the busiest thread first, the idle ones summed
    assert [kv.key for kv in status.values][-3:] == ["cores main", "cores loop-closer_0",
                                                     "cores other threads"]
    assert values["cores other threads"] == "0.006"
    assert values["loop_work_waiting"] == "0" and values["looks_overdue"] == "0"


def test_a_late_map_or_a_trimmed_edge_warns_and_says_why() -> None:
    status, values = _values(EdgeLoad(
        devices=2, answered=[(1.4, 1.0), (0.2, 1.0)], load=0.7, budget=0.6,
        level="no local bundle adjustment, no new loop search or place look", trimmed=True))
    assert status.level == DiagnosticStatus.WARN
    assert "over its compute budget: no local bundle adjustment" in status.message
    assert "1 of 2 maps later than their slot" in status.message
    assert values["slots_late"] == "1"
    status, values = _values(EdgeLoad(devices=1, answered=[], load=0.0, budget=0.0,
                                      level="bundle adjustment of 5 keyframes, 120 points",
                                      trimmed=False))
    assert status.level == DiagnosticStatus.OK and values["latency_ms_median"] == ""
    assert status.message == "1 device, 0 slots answered, slot work 0% of a core"


def test_place_looks_held_past_their_bound_behind_the_loops_warn_and_the_queue_is_shown() -> None:
    """A worker the loop jobs keep busy holds the place looks back (devices merge late): the
    looks that waited past their bound in the period warn, and the queue's two kinds are
    values."""
    status, values = _values(EdgeLoad(
        devices=12, answered=[(0.4, 1.0)], load=0.5, budget=0.0, level="no budget",
        trimmed=False, worker_waiting=(7, 3), looks_overdue=2))
    assert status.level == DiagnosticStatus.WARN
    assert "2 place looks waited past their bound behind the loop jobs" in status.message
    assert values["loop_work_waiting"] == "7" and values["looks_waiting"] == "3"
    assert values["looks_overdue"] == "2"
