"""Noticing that the edge stopped answering, without DDS.

After each slot the device sends its frame summaries and expects an ``UploadRequest``. When
none comes within ``timeout_s`` (a link down, an edge restarting), the device says once that it
goes on tracking on its local map; when the edge answers again, it says after how long. The
clock is injected, so tests drive the silence without waiting. The tracking thread says when
summaries went out, the node's executor when a request came and when to check: a lock keeps
the two apart.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class EdgeWatchdog:
    def __init__(self, timeout_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if timeout_s <= 0:
            raise ValueError(f"edge timeout must be > 0 s, got {timeout_s}")
        self.timeout_s = timeout_s
        self.clock = clock
        self.unanswered: dict[int, float] = {}   #: slot → when its summaries went out
        self.silent_since: float | None = None
        self._lock = threading.Lock()

    def asked(self, slot: int) -> None:
        """The summaries of ``slot`` went out."""
        with self._lock:
            self.unanswered[slot] = self.clock()

    def answered(self, slot: int) -> float | None:
        """An upload request for ``slot`` came (older slots will not be answered now); the
        seconds of silence it ends, or None if the edge had not been silent."""
        with self._lock:
            for old in [k for k in self.unanswered if k <= slot]:
                del self.unanswered[old]
            if self.silent_since is None:
                return None
            silence = self.clock() - self.silent_since
            self.silent_since = None
            return silence

    def check(self) -> tuple[int, float] | None:
        """(slot, seconds waited) the first time the oldest unanswered slot has waited more
        than ``timeout_s``; None otherwise, and while the edge is already known silent."""
        with self._lock:
            if self.silent_since is not None or not self.unanswered:
                return None
            slot = min(self.unanswered)
            waited = self.clock() - self.unanswered[slot]
            if waited <= self.timeout_s:
                return None
            self.silent_since = self.unanswered[slot]
            return slot, waited
