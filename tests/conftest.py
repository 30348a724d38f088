"""Shared fixtures: a private loopback DDS domain per test, and an in-process ROS context."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import node_runtime
from node_runtime.loopback import LoopbackDomain


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
