"""The update loop's stages from what a monitor heard: a hand-made run whose every time is
known, a slot whose uploads were never reported, and the table of medians."""

from __future__ import annotations

import math

import numpy as np
import pytest

from device_tracker.messages import FrameRecord, frame_summaries_message
from twinslam.live.run_log import RunLog
from twinslam.live.update_loop import stage_table, update_loop_latencies


def _frame(frame_id: int, stamp: float, version: int, slot: int) -> FrameRecord:
    return FrameRecord(frame_id, stamp, np.eye(4), True, np.zeros(0, np.uint64),
                       np.zeros(0, np.uint64), slot, False, 40, version)


def _run() -> RunLog:
    record = RunLog()
    slots = {0: [_frame(0, 10.0, 0, 0), _frame(1, 10.1, 0, 0)],
             1: [_frame(2, 10.2, 0, 1), _frame(3, 10.3, 0, 1)],
             2: [_frame(4, 11.05, 1, 2), _frame(5, 11.1, 1, 2)]}
    for slot, frames in slots.items():
        record.summaries[slot] = frame_summaries_message(slot, 40.0, 0, 0, frames, 0.0)
    # slot 0: every message heard; its map (version 1) is first used by frame 4 at 11.05
    for topic, t in (("summaries", 10.15), ("request", 10.25), ("throughput", 10.75),
                     ("map", 11.0)):
        record.hear(topic, 0, t)
    record.first_map_versions[0] = 1
    # slot 1: no throughput report; its map (version 2) is used by no later frame
    for topic, t in (("summaries", 10.35), ("request", 10.4), ("map", 11.5)):
        record.hear(topic, 1, t)
    record.first_map_versions[1] = 2
    return record


def test_each_stage_is_the_time_between_what_the_monitor_heard() -> None:
    record = _run()
    record.hear("map", 0, 12.0)               # the slot's map sent again later: the first counts
    first, second = update_loop_latencies(record)
    assert first.slot == 0
    assert (first.summaries_s, first.decision_s, first.uploads_s, first.integration_s,
            first.to_device_s) == pytest.approx((0.05, 0.10, 0.50, 0.25, 0.05))
    assert first.total_s == pytest.approx(11.05 - 10.1)
    # slot 2's summaries were never heard: no row; slot 1's unheard stages are NaN
    assert second.slot == 1 and second.summaries_s == pytest.approx(0.05)
    assert math.isnan(second.uploads_s) and math.isnan(second.integration_s)
    assert math.isnan(second.to_device_s) and math.isnan(second.total_s)


def test_a_message_heard_after_the_one_it_caused_counts_as_heard_with_it() -> None:
    """On a loaded host the monitor heard an edge's request 0.15 ms before the summaries that
    caused it: the decision reads zero, never less, and the summaries' stage ends with it."""
    record = _run()
    record.heard["summaries"][0] = 10.25015   # after the request (10.25) it caused
    first, _ = update_loop_latencies(record)
    assert first.decision_s == 0.0
    assert first.summaries_s == pytest.approx(10.25 - 10.1)
    assert first.uploads_s == pytest.approx(0.50)           # the later stages as they were
    assert first.total_s == pytest.approx(11.05 - 10.1)


def test_a_map_heard_before_the_uploads_report_leaves_the_uploads_as_heard() -> None:
    """The map update comes of the keyframes, not of the device's report of sending them: a
    report heard after the map keeps its stage, and the integration stage reads below zero."""
    record = _run()
    record.heard["throughput"][0] = 11.02        # after the map (11.0)
    first, _ = update_loop_latencies(record)
    assert first.uploads_s == pytest.approx(11.02 - 10.25)
    assert first.integration_s == pytest.approx(-0.02)


def test_the_stage_table_takes_medians_over_the_slots_that_measured_a_stage() -> None:
    rows = {name: (median, count) for name, median, _, count
            in stage_table(update_loop_latencies(_run()))}
    assert list(rows) == ["summaries", "decision", "uploads", "integration", "to_device",
                          "total"]
    assert rows["summaries"] == (pytest.approx(0.05), 2)
    assert rows["decision"] == (pytest.approx(0.075), 2)
    assert rows["uploads"] == (pytest.approx(0.5), 1) and rows["total"][1] == 1
    assert math.isnan(stage_table([])[0][1])
