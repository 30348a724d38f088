"""Shared fixtures: a private ROS domain per test, and an in-process rclpy node on it."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from twinslam.node_hosts.loopback import LoopbackDomain
from twinslam.node_hosts.session import RosSession


@pytest.fixture
def domain() -> Iterator[LoopbackDomain]:
    with LoopbackDomain() as dom:
        dom.activate()
        yield dom


@pytest.fixture
def ros(domain: LoopbackDomain) -> Iterator[RosSession]:
    """A node (``ros.node``) on the test's domain and bounded spinning (``ros.spin_until``)."""
    with RosSession("test_driver") as session:
        yield session
