"""How much of a core each of this process's threads took lately, by the name Linux shows for
it: what a node reports on ``/diagnostics`` so that a user of a loaded edge sees whether its
slot thread, its loop closer's worker or its keyframe database's word learning takes the cores
(the threads name themselves: :mod:`twinslam.thread_names`) — from ``rqt_runtime_monitor`` or
Foxglove's diagnostics panel, without a profiler. Read from ``/proc/self/task``: Linux only;
elsewhere nothing is reported.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

#: the process's own thread (its id is the process's), whatever name it shows
MAIN = "main"
_TASKS = Path("/proc/self/task")
_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01


def stat_cpu(stat: str) -> tuple[str, list[str], float]:
    """(name, the fields after it, CPU seconds: user + system) of a ``/proc/PID/stat`` or
    ``/proc/PID/task/TID/stat`` line (the name in parentheses may hold spaces and
    parentheses itself: it ends at the line's last ")")."""
    comm = stat[stat.index("(") + 1:stat.rindex(")")]
    fields = stat[stat.rindex(")") + 2:].split()
    return comm, fields, (int(fields[11]) + int(fields[12])) * _TICK_S


def thread_cpu_seconds() -> dict[str, float]:
    """CPU seconds (user + system) each named thread of this process has used, threads of
    one name summed (the main thread as MAIN); {} where ``/proc`` has no threads."""
    out: dict[str, float] = {}
    main = os.getpid()
    try:
        tasks = list(_TASKS.iterdir())
    except OSError:
        return out
    for task in tasks:
        try:
            stat = (task / "stat").read_text()
        except OSError:                          # the thread ended meanwhile
            continue
        comm, _, cpu = stat_cpu(stat)
        name = MAIN if int(task.name) == main else comm
        out[name] = out.get(name, 0.0) + cpu
    return out


class ThreadLoad:
    """Each thread name's share of a core between two readings (:meth:`cores`). A thread that
    ended between them is left out: its CPU is no longer counted anywhere."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 read: Callable[[], dict[str, float]] = thread_cpu_seconds) -> None:
        self._clock, self._read = clock, read
        self._at, self._seconds = clock(), read()

    def cores(self) -> dict[str, float]:
        """Share of one core each thread name took since the last call (or since made)."""
        now, seconds = self._clock(), self._read()
        span = max(now - self._at, 1e-9)
        shares = {name: max(0.0, used - self._seconds.get(name, 0.0)) / span
                  for name, used in seconds.items()}
        self._at, self._seconds = now, seconds
        return shares
