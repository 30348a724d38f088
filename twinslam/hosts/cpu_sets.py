"""Node processes held to some of this machine's cores: emulated hosts of a given size.

Network-namespace hosts (:mod:`twinslam.hosts.netns`) give each emulated edge host its own
network stack but not its own cores: every process may run on any core of the machine, so two
"2-core edge hosts" on an 8-core machine share eight cores, and a figure measured that way
says nothing about a 2-core host. Held to a CPU set of their own (Linux's affinity mask, what
``taskset -c`` sets), the processes of one emulated host compete for its cores only — as a
machine of that many cores would give them — and the devices' emulator for the cores left to
it.

CPU lists are written as ``taskset -c`` and the kernel's ``cpuset`` files write them:
``0-1``, ``2,3``, ``0-3,8``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any


class CpuSetError(ValueError):
    """A CPU list that cannot be read, or that names cores this process may not run on."""


def parse_cpu_list(text: str) -> frozenset[int]:
    """The cores a CPU list names (``0-1``, ``2,3``, ``0-3,8``); raises :class:`CpuSetError`
    for one that is empty or malformed."""
    cores: set[int] = set()
    for part in text.strip().split(","):
        first, dash, last = part.strip().partition("-")
        try:
            low = int(first)
            high = int(last) if dash else low
        except ValueError:
            raise CpuSetError(f"{text!r}: a CPU list is cores and ranges joined by commas "
                              f"(0-1, 2,3, 0-3,8), not {part.strip()!r}") from None
        if low < 0 or high < low:
            raise CpuSetError(f"{text!r}: {part.strip()!r} is no range of cores")
        cores.update(range(low, high + 1))
    return frozenset(cores)


def usable(cores: frozenset[int]) -> frozenset[int]:
    """``cores``, checked against the cores this process may run on (its own affinity, which
    a container or a ``taskset`` may have narrowed): raises :class:`CpuSetError` naming any
    it may not use."""
    allowed = os.sched_getaffinity(0)
    outside = sorted(cores - allowed)
    if outside:
        raise CpuSetError(f"cores {', '.join(map(str, outside))} are not among this "
                          f"machine's usable cores ({format_cpu_list(frozenset(allowed))})")
    return cores


def format_cpu_list(cores: frozenset[int]) -> str:
    """``cores`` as a CPU list, runs of neighbours as ranges (``0-3,8``)."""
    runs: list[str] = []
    ordered = sorted(cores)
    start = prev = None
    for core in [*ordered, None]:
        if core is not None and prev is not None and core == prev + 1:
            prev = core
            continue
        if start is not None:
            runs.append(str(start) if start == prev else f"{start}-{prev}")
        start = prev = core
    return ",".join(runs)


def cycled(sets: Sequence[frozenset[int]], count: int) -> list[frozenset[int] | None]:
    """The CPU set of each of ``count`` processes: the k-th process gets set k mod
    len(``sets``) (``0-1 0-1 2-3 2-3`` puts four edge processes on two 2-core hosts); None for
    each where no sets are given (the process runs anywhere)."""
    if not sets:
        return [None] * count
    return [sets[k % len(sets)] for k in range(count)]


def held_to(cores: frozenset[int] | None) -> dict[str, Any]:
    """Keyword arguments for :func:`subprocess.Popen` (and
    :meth:`~twinslam.hosts.loopback.LoopbackDomain.spawn`) that start a process held to
    ``cores``: set in the child before it runs anything, so that every thread it starts
    (DDS's, the math pools', the loop worker) inherits the set. None: no arguments, the
    process runs where the caller may."""
    if cores is None:
        return {}
    chosen = set(cores)

    def hold() -> None:
        os.sched_setaffinity(0, chosen)

    return {"preexec_fn": hold}
