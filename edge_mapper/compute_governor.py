"""The edge's compute budget: an edge serving many devices must answer each slot
within its period, and past ~16 devices a 2-core edge does not (BENCHMARKS.md,
bench.edge_scaling). Of an edge's per-slot work — planning, integrating keyframes, local
bundle adjustment, the map update — the bundle adjustment is the part that can shrink without
breaking the protocol: a smaller window of keyframes optimised, fewer points, or none. Past
it, with loop closing or map merging on, the worker starts no new search — no loop search,
no look for a device's place in the other devices' maps (:attr:`ComputeLevel.searches`): the
worker shares the process's interpreter and the host's cores with the slots, and on an edge
past its cores it closed no loop anyway — fifty devices on two edge processes of a 2-core
host closed none and paid 11–13 ms of a core a device-slot for it
(docs/results/shared-map.md, "Fifty devices without the loop closer"); the looks of fifty
devices of which half share a place took a fifth of the edges' CPU ("Fifty devices
at places of their own").

The governor measures the compute the edge spends (seconds of slot work per second of wall
time, over a sliding window) against ``budget`` (a share of one core: the edge's Python work
runs on one) and steps through :data:`LEVELS` — trimming the bundle adjustment when over the
budget, restoring it when the load has fallen below ``relax`` × the budget, at most one step
per half window so that each step's effect is seen before the next. Pure logic: the node
charges it and applies the level it returns to every device's core.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class ComputeLevel:
    """What of its optional work the edge does at one step of the budget."""

    window: int                      #: newest keyframes optimised (0: no bundle adjustment)
    points: int | None               #: points in it at most (None: all)
    #: the worker starts new searches, for loops and for devices' places (False: none until
    #: the load falls; a search running goes on, and the newest keyframes wait to look when
    #: the searches resume)
    searches: bool = True

    def describe(self) -> str:
        if self.window == 0:
            adjustment = "no local bundle adjustment"
        else:
            adjustment = (f"bundle adjustment of {self.window} keyframes, "
                          f"{self.points or 'all'} points")
        return adjustment if self.searches else f"{adjustment}, no new loop search or place look"


#: from the full local bundle adjustment (the edge's defaults) down to none
LEVELS = (ComputeLevel(5, 120), ComputeLevel(3, 60), ComputeLevel(1, 30), ComputeLevel(0, 0))
#: the last step, with loop closing or map merging on: no adjustment and no new search
NO_NEW_SEARCH = ComputeLevel(0, 0, searches=False)


def levels_within(window: int, points: int | None, searches: bool = False
                  ) -> tuple[ComputeLevel, ...]:
    """The levels a governor may step through for an edge configured with ``window`` and
    ``points``: that adjustment first, then the smaller of :data:`LEVELS`, then — for an edge
    that closes loops or merges maps (``searches``) — :data:`NO_NEW_SEARCH`. A budget only
    trims: it never turns on an adjustment the edge was told not to run (``window`` 0 without
    searches: the one level, none)."""
    first = ComputeLevel(window, points if window else 0)
    smaller = (level for level in LEVELS if level.window < window)
    return (first, *smaller, *((NO_NEW_SEARCH,) if searches else ()))


class ComputeGovernor:
    """``budget``: the share of one core the edge's slot work may take (0: no budget)."""

    def __init__(self, budget: float, window_s: float = 10.0, relax: float = 0.6,
                 levels: tuple[ComputeLevel, ...] = LEVELS) -> None:
        if budget < 0 or window_s <= 0 or not 0 < relax < 1:
            raise ValueError("budget must be >= 0, window_s > 0 and relax in (0, 1)")
        self.budget, self.window_s, self.relax, self.levels = budget, window_s, relax, levels
        self.level = 0
        self._spent: deque[tuple[float, float]] = deque()     #: (time, seconds of work)
        self._started: float | None = None
        self._last_step = -float("inf")

    def charge(self, seconds: float, now: float) -> None:
        """``seconds`` of slot work finished at ``now`` (monotonic seconds)."""
        if self._started is None:
            self._started = now
        self._spent.append((now, max(0.0, seconds)))
        while self._spent and self._spent[0][0] < now - self.window_s:
            self._spent.popleft()

    def load(self, now: float) -> float:
        """Seconds of work per second over the last window (a share of one core)."""
        if self._started is None:
            return 0.0
        span = min(self.window_s, max(now - self._started, 1e-3))
        return sum(s for t, s in self._spent if t >= now - self.window_s) / span

    def step(self, now: float) -> ComputeLevel | None:
        """The new level when the load calls for one (None: unchanged)."""
        if self.budget <= 0 or now - self._last_step < self.window_s / 2:
            return None
        if self._started is None or now - self._started < self.window_s / 2:
            return None                  # too little seen to judge
        load = self.load(now)
        if load > self.budget and self.level < len(self.levels) - 1:
            self.level += 1
        elif load < self.relax * self.budget and self.level > 0:
            self.level -= 1
        else:
            return None
        self._last_step = now
        return self.levels[self.level]
