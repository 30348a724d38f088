"""Hostile bytes at every message type a twinslam node subscribes to (issue #8).

Each payload goes through the subscription's own path (``Subscription.handle``: CDR decoding,
validation, callback or a logged rejection), as a sample taken off the wire would. Hypothesis
draws truncated, extended and random payloads and bit flips of real ones for at most ~40 s in
all; a deterministic sweep then writes 0xFFFFFFFF (a 4 GB length) into every aligned word of
each type's sample and checks that nothing near that size is allocated.
"""

from __future__ import annotations

import logging
import re
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import node_runtime
from msg_schemas import cdr, new

REPO = Path(__file__).resolve().parents[1]
NODE_FILES = ["device_tracker/node.py", "edge_mapper/node.py", "udt_node/node.py"]
SUBSCRIBED = sorted({"sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                     "twinslam_msgs/msg/UploadRequest", "twinslam_msgs/msg/MapUpdate",
                     "twinslam_msgs/msg/FrameSummaries", "twinslam_msgs/msg/Keyframe",
                     "twinslam_msgs/msg/UplinkThroughput", "twinslam_msgs/msg/RateLatent"})
BUDGET_S = 40.0                       #: hypothesis time over all types (CI: ≤ 60 s in all)
tried: dict[str, int] = {}


def _sample(type_name: str) -> bytes:
    """A well-formed sample with content in its sequences, so mutations hit real lengths."""
    fields: dict[str, Any] = {}
    if type_name == "sensor_msgs/msg/Image":
        fields = {"height": 2, "width": 3, "encoding": "mono8", "step": 3,
                  "data": np.arange(6, dtype=np.uint8)}
    elif type_name == "twinslam_msgs/msg/Keyframe":
        fields = {"keypoints_xy": np.ones(4, np.float32), "keypoint_depths": np.ones(2, np.float32),
                  "descriptors": np.zeros(64, np.uint8), "map_point_ids": np.ones(2, np.uint64)}
    elif type_name == "twinslam_msgs/msg/RateLatent":
        fields = {"mu": np.zeros(4, np.float32), "sigma": np.ones(4, np.float32),
                  "next_state_probs": np.full(2, 0.5, np.float32),
                  "state_rates_mbps": np.array([40.0, 80.0])}
    elif type_name == "twinslam_msgs/msg/UploadRequest":
        fields = {"upload_frame_ids": np.array([3, 4], np.uint64), "policy": "adapt"}
    msg = new(type_name, **fields)
    return cdr.serialize(msg)


def test_the_fuzzed_types_are_every_type_the_nodes_subscribe_to() -> None:
    found = set()
    for rel in NODE_FILES:
        text = (REPO / rel).read_text()
        found |= set(re.findall(r'create_subscription\(\s*"([\w/]+)"', text))
    assert found == set(SUBSCRIBED)


@pytest.fixture
def subscriptions(ros: node_runtime.SingleThreadedExecutor) -> dict[str, Any]:
    node = node_runtime.Node("fuzz_target")
    accepted: list[Any] = []
    return {t: node.create_subscription(t, f"/fuzz/{t.split('/')[-1].lower()}",
                                        accepted.append, node_runtime.PROTOCOL)
            for t in SUBSCRIBED}


def _mutations() -> st.SearchStrategy[tuple[str, bytes]]:
    def mutate(draw: Any) -> tuple[str, bytes]:
        type_name = draw(st.sampled_from(SUBSCRIBED))
        good = _sample(type_name)
        kind = draw(st.sampled_from(["truncate", "extend", "random", "flip", "length"]))
        if kind == "truncate":
            return type_name, good[:draw(st.integers(0, len(good) - 1))]
        if kind == "extend":
            return type_name, good + draw(st.binary(min_size=1, max_size=4096))
        if kind == "random":
            return type_name, draw(st.binary(max_size=2048))
        data = bytearray(good)
        at = draw(st.integers(0, len(data) - 4))
        if kind == "flip":
            data[at] ^= 1 << draw(st.integers(0, 7))
        else:
            data[at:at + 4] = draw(st.integers(0, 2**32 - 1)).to_bytes(4, "little")
        return type_name, bytes(data)

    return st.composite(mutate)()


class _Errors(logging.Handler):
    """Counts the error records a node's logger emits."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def test_hostile_payloads_are_rejected_and_logged_never_crash(
        subscriptions: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    errors = _Errors()
    logging.getLogger("ros.fuzz_target").addHandler(errors)
    started = time.monotonic()
    deadline = started + BUDGET_S

    @settings(max_examples=20000, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(_mutations())
    def throw(case: tuple[str, bytes]) -> None:
        if time.monotonic() > deadline:
            return
        type_name, payload = case
        tried[type_name] = tried.get(type_name, 0) + 1
        subscriptions[type_name].handle(payload)        # must not raise

    throw()
    rejected = sum(s.rejected for s in subscriptions.values())
    received = sum(s.received for s in subscriptions.values())
    assert rejected + received == sum(tried.values())
    assert rejected > 0.5 * sum(tried.values())
    logged = sum("dropped a malformed" in m for m in errors.messages)
    assert logged == rejected, "every rejection is logged"
    with capsys.disabled():
        print(f"\nfuzz: {sum(tried.values())} hostile payloads in "
              f"{time.monotonic() - started:.1f} s, "
              f"{rejected} rejected and logged, {received} well-formed after mutation; "
              f"per type: {dict(sorted(tried.items()))}")


def test_a_4_gb_length_anywhere_allocates_nothing_of_that_size(
        subscriptions: dict[str, Any]) -> None:
    tracemalloc.start()
    try:
        for type_name, sub in subscriptions.items():
            good = _sample(type_name)
            for at in range(4, len(good) - 3, 4):        # every aligned word after the header
                data = bytearray(good)
                data[at:at + 4] = b"\xff\xff\xff\xff"
                sub.handle(bytes(data))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, f"peak {peak / 2**20:.0f} MiB while decoding 4 GB lengths"
    assert all(s.rejected > 0 for s in subscriptions.values())
