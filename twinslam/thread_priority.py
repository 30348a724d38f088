"""Running the calling thread below the others of its process, for background work (the loop
closer's worker, the keyframe database's words) that must leave the slots' threads the cores.

Linux gives each thread a nice value of its own (``setpriority`` on its thread id): a thread
that lowers its own priority needs no privilege, and the process's other threads keep theirs.
Elsewhere the call would move the whole process, so the thread keeps the slots' priority
there. Native code that releases the interpreter's lock (faiss' k-means, GTSAM) is where a
nice value matters: Python code of one process shares one interpreter, which a nice value does
not reach.
"""

from __future__ import annotations

import os
import sys
import threading

#: whether a thread's nice value is its own (Linux)
PER_THREAD_NICE = sys.platform.startswith("linux")


def check_niceness(steps: int) -> None:
    """Refuse a niceness outside Linux's 0–19 steps (ValueError), before any thread uses it."""
    if not 0 <= steps <= 19:
        raise ValueError(f"a niceness is 0 to 19 steps, not {steps}")


def lower_this_thread(steps: int, above: int | None = None) -> int | None:
    """Set the calling thread's nice value ``steps`` (0–19) above ``above`` (None: its own
    now), at most 19; its nice value after, or None where threads have none of their own. A
    sandbox that refuses the call leaves the priority as it was."""
    check_niceness(steps)
    if not PER_THREAD_NICE:
        return None
    own = threading.get_native_id()
    start = os.getpriority(os.PRIO_PROCESS, own) if above is None else above
    if steps:
        try:
            os.setpriority(os.PRIO_PROCESS, own, min(19, start + steps))
        except OSError:
            pass
    return os.getpriority(os.PRIO_PROCESS, own)
