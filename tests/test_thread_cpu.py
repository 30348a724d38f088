"""Each named thread's share of a core, as an edge reports it on /diagnostics: a busy thread
that named itself shows under its name, and the shares are CPU over wall time between two
readings."""

from __future__ import annotations

import sys
import threading
import time

import pytest

from twinslam.node_runtime.thread_cpu import MAIN, ThreadLoad, thread_cpu_seconds
from twinslam.thread_names import name_this_thread


def test_the_shares_are_each_names_cpu_over_the_time_between_two_readings() -> None:
    clock, readings = [10.0], [{MAIN: 1.0, "loop-closer_0": 0.5},
                               {MAIN: 1.6, "loop-closer_0": 0.7, "place-words": 0.3}]
    load = ThreadLoad(clock=lambda: clock[0], read=lambda: readings.pop(0))
    clock[0] = 12.0
    assert load.cores() == pytest.approx({MAIN: 0.3, "loop-closer_0": 0.1,
                                          "place-words": 0.15})


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc's threads are Linux's")
def test_a_busy_thread_that_named_itself_shows_under_its_name() -> None:
    stop = threading.Event()

    def spin() -> None:
        name_this_thread("busy-for-test")
        while not stop.is_set():
            sum(range(1000))

    load = ThreadLoad()
    thread = threading.Thread(target=spin, name="busy-for-test")
    thread.start()
    try:
        deadline = time.monotonic() + 30.0       # until the scheduler gave it a few ticks
        while thread_cpu_seconds().get("busy-for-test", 0.0) < 0.2 and \
                time.monotonic() < deadline:
            time.sleep(0.05)
        shares = load.cores()
    finally:
        stop.set()
        thread.join(5.0)
    assert shares.get("busy-for-test", 0.0) > 0
    assert MAIN in shares
