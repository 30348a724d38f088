"""Shared fixtures: a private loopback DDS domain per test, and an in-process ROS context."""

from __future__ import annotations

import json
import queue
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import node_runtime
from node_runtime.loopback import LoopbackDomain

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture
def domain() -> Iterator[LoopbackDomain]:
    with LoopbackDomain() as dom:
        dom.activate()
        yield dom


@pytest.fixture
def ros(domain: LoopbackDomain) -> Iterator[node_runtime.SingleThreadedExecutor]:
    """An initialised runtime on the test's domain and an executor to spin it (bounded)."""
    node_runtime.init(args=["test"], install_signal_handlers=False)
    executor = node_runtime.SingleThreadedExecutor()
    yield executor
    node_runtime.shutdown()


class JsonLines:
    """Reads a child's stdout JSON lines on a thread, so waiting on them is bounded in time."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: queue.Queue[dict] = queue.Queue()
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.strip()
            if line.startswith("{"):
                self.lines.put(json.loads(line))

    def next(self, event: str, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"no {event!r} line within {timeout} s "
                                   f"(process exit code {self.proc.poll()})")
            try:
                item = self.lines.get(timeout=remaining)
            except queue.Empty:
                continue
            if item.get("event") == event:
                return item
