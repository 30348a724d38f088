"""A background thread lowers its own priority and no other thread's: the keyframe database's
words and the loop closer's worker give the slots' threads the cores."""

from __future__ import annotations

import os
import threading

import pytest

from twinslam.thread_priority import PER_THREAD_NICE, lower_this_thread

pytestmark = pytest.mark.skipif(not PER_THREAD_NICE, reason="threads have no nice value of "
                                "their own here")


def _in_thread(steps: int, above: int | None = None) -> tuple[int | None, int]:
    """What ``lower_this_thread`` returned in a thread of its own, and that thread's nice
    value read by its id afterwards (while it still runs)."""
    seen: dict[str, int | None] = {}
    done, read = threading.Event(), threading.Event()

    def run() -> None:
        seen["returned"] = lower_this_thread(steps, above)
        seen["tid"] = threading.get_native_id()
        done.set()
        read.wait(5.0)

    thread = threading.Thread(target=run)
    thread.start()
    assert done.wait(5.0)
    tid = seen["tid"]
    assert tid is not None
    nice = os.getpriority(os.PRIO_PROCESS, tid)
    read.set()
    thread.join(5.0)
    return seen["returned"], nice


def test_a_thread_lowers_its_own_priority_and_leaves_the_callers() -> None:
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    returned, nice = _in_thread(5)
    assert returned == nice == min(19, mine + 5)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine


def test_the_lowest_priority_is_nineteen_and_zero_steps_change_nothing() -> None:
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    assert _in_thread(19)[1] == 19
    assert _in_thread(0) == (mine, mine)
    with pytest.raises(ValueError, match="0 to 19"):
        lower_this_thread(20)
