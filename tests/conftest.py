"""Shared fixtures: a private ROS domain per test, and an in-process rclpy node on it; and the
order in which parallel workers (pytest-xdist, ``make test``) take the tests."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

# One math thread in every test process and in the processes a test starts (set before torch
# or NumPy's OpenBLAS load): parallel workers share the cores, and a thread pool per core in each
# of them oversubscribes the machine (measured on 2 cores, 3 workers: the twin's ELBO test took
# 65 s of CPU instead of 15). A test of thread settings clears it for what it starts.
os.environ.setdefault("OMP_NUM_THREADS", "1")
# The live tests play the same frames dozens of times (the 7-Scenes sample, the synthetic
# worlds' walks): every player and calibration the suite starts reads a frame made once through
# one cache of decoded and rendered frames (twinslam.sequences.decoded_frames), kept between
# runs under .cache/ — about 1 500 frames, 3.2 GB, in one run of the suite; bounded at 4 GB. A
# 2-core machine's suite is CPU-bound, and the players' CPU fell by ~40 % (docs/testing.md).
os.environ.setdefault("TWINSLAM_FRAME_CACHE",
                      str(Path(__file__).resolve().parents[1] / ".cache" / "decoded-frames"))
os.environ.setdefault("TWINSLAM_FRAME_CACHE_GB", "4")

from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession


def _expected_seconds(item: pytest.Item) -> float:
    """How long a ``slow`` test takes (``slow(seconds=...)``, measured on 2 cores beside the
    other workers; 30 when not given); 0 for the others."""
    marker = item.get_closest_marker("slow")
    return 0.0 if marker is None else float(marker.kwargs.get("seconds", 30))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The ``slow`` tests first, the longest first (stable otherwise): handed out last, a
    minute-long test would keep one worker busy after the others ran out of work."""
    items.sort(key=lambda item: -_expected_seconds(item))


@pytest.fixture
def domain() -> Iterator[LoopbackDomain]:
    with LoopbackDomain() as dom:
        dom.activate()
        yield dom


@pytest.fixture
def cyclone(domain: LoopbackDomain) -> Iterator[Callable[[], Any]]:
    """Makes Cyclone DDS participants on the test's domain (``tests/cyclone_peer.py``: the
    nodes' outside peer), each deleted with its readers and writers when the test ends —
    before the domain's id goes back to the machine."""
    from tests import cyclone_peer

    made: list[Any] = []

    def make() -> Any:
        made.append(cyclone_peer.participant(domain.domain_id))
        return made[-1]

    yield make
    for dp in made:
        cyclone_peer.delete(dp)


@pytest.fixture
def ros(domain: LoopbackDomain) -> Iterator[RosSession]:
    """A node (``ros.node``) on the test's domain and bounded spinning (``ros.spin_until``)."""
    with RosSession("test_driver") as session:
        yield session
