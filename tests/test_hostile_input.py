"""Hostile bytes at every message type a twinslam node subscribes to.

In process, each payload goes through the subscription's own path
(:meth:`~twinslam.node_runtime.checked_subscription.CheckedSubscription.handle`: rclpy's CDR
decoding, validation, the callback or a logged rejection), as a sample taken off the wire would:
Hypothesis draws truncated, extended and random payloads and bit flips of real ones (4 000, ~5 s); a
deterministic sweep writes 0xFFFFFFFF (a 4 GB length) into every aligned word of each type's
sample under ``tracemalloc``. Over DDS, the real device, edge and twin processes get hostile
samples on every topic they read from a raw Cyclone DDS writer (``tests.cyclone_peer``: another
vendor, which sends bytes no rclpy writer would) and must log them, stay up, keep their state
and keep answering.
"""

from __future__ import annotations

import functools
import re
import subprocess
import sys
import time
import tracemalloc
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import serialize_message

from msg_schemas import message_class, new, qos
from tests import cyclone_peer
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.session import RosSession

REPO = Path(__file__).resolve().parents[1]
NODE_FILES = ["device_tracker/node.py", "device_tracker/relocalisation_requests.py",
              "edge_mapper/node.py", "edge_mapper/device_link.py",
              "udt_node/node.py", "twinslam/sequence_player/node.py"]
SUBSCRIBED = sorted({"sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                     "twinslam_msgs/msg/UploadRequest", "twinslam_msgs/msg/MapUpdate",
                     "twinslam_msgs/msg/FrameSummaries", "twinslam_msgs/msg/Keyframe",
                     "twinslam_msgs/msg/UplinkThroughput", "twinslam_msgs/msg/RateLatent",
                     "twinslam_msgs/msg/RelocalisationRequest",
                     "twinslam_msgs/msg/Relocalisation", "twinslam_msgs/msg/PlaybackPace"})
#: hostile payloads drawn over all types (~360 a type): a count, not a wall-clock budget, so
#: that a loaded machine tries as many as an idle one and an idle one spends no more CPU than
#: it needs (a 16 s budget drew 8 000 here alone and fewer beside the suite's other workers)
PAYLOADS = 4000
tried: dict[str, int] = {}

#: node processes forked as the launchers fork theirs (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


@functools.cache
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
    elif type_name == "twinslam_msgs/msg/RelocalisationRequest":
        fields = {"keypoints_xy": np.ones(4, np.float32), "descriptors": np.zeros(64, np.uint8)}
    elif type_name == "twinslam_msgs/msg/PlaybackPace":
        fields = {"camera": "/ar2/sequence_player", "waiting_for_device": True,
                  "held": new("builtin_interfaces/msg/Duration", sec=2, nanosec=500)}
    return serialize_message(new(type_name, **fields))


def test_the_fuzzed_types_are_every_type_the_nodes_subscribe_to() -> None:
    found = set()
    for rel in NODE_FILES:
        text = (REPO / rel).read_text()
        found |= set(re.findall(r"CheckedSubscription\(\s*(?:self|node),\s*(\w+),", text))
    assert found == {t.rsplit("/", 1)[1] for t in SUBSCRIBED}


class _Recorder:
    """Stands in for a node's logger: keeps the errors it is given."""

    def __init__(self) -> None:
        self.errors: list[str] = []

    def error(self, message: str) -> None:
        self.errors.append(message)


@pytest.fixture
def subscriptions(ros: RosSession) -> dict[str, CheckedSubscription]:
    accepted: list[Any] = []
    subs = {t: CheckedSubscription(ros.node, message_class(t),
                                   f"fuzz/{t.split('/')[-1].lower()}", accepted.append,
                                   qos.PROTOCOL) for t in SUBSCRIBED}
    log = _Recorder()
    for sub in subs.values():
        sub._logger = log           # type: ignore[assignment]
    return subs


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


def test_hostile_payloads_are_rejected_and_logged_never_crash(
        subscriptions: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    started = time.monotonic()

    @settings(max_examples=PAYLOADS, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(_mutations())
    def throw(case: tuple[str, bytes]) -> None:
        type_name, payload = case
        tried[type_name] = tried.get(type_name, 0) + 1
        subscriptions[type_name].handle(payload)        # must not raise

    throw()
    rejected = sum(s.rejected for s in subscriptions.values())
    received = sum(s.received for s in subscriptions.values())
    assert sum(tried.values()) >= 0.9 * PAYLOADS and set(tried) == set(SUBSCRIBED)
    assert rejected + received == sum(tried.values())
    assert rejected > 0.5 * sum(tried.values())
    errors = next(iter(subscriptions.values()))._logger.errors
    logged = sum("dropped a malformed" in m for m in errors)
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


#: what each node subscribes to (absolute names: the nodes run in the root namespace)
NODE_TOPICS = {
    "device_tracker": [("sensor_msgs/msg/Image", "/camera/image_raw"),
                       ("sensor_msgs/msg/Image", "/camera/depth/image_raw"),
                       ("sensor_msgs/msg/CameraInfo", "/camera/camera_info"),
                       ("twinslam_msgs/msg/UploadRequest", "/edge/upload_request"),
                       ("twinslam_msgs/msg/MapUpdate", "/edge/map_update"),
                       ("twinslam_msgs/msg/Relocalisation", "/edge/relocalisation")],
    "edge_mapper": [("twinslam_msgs/msg/FrameSummaries", "/device/frame_summaries"),
                    ("twinslam_msgs/msg/Keyframe", "/device/keyframes"),
                    ("twinslam_msgs/msg/UplinkThroughput", "/device/uplink_throughput"),
                    ("twinslam_msgs/msg/RateLatent", "/udt/rate_latent"),
                    ("twinslam_msgs/msg/RelocalisationRequest",
                     "/device/relocalisation_request")],
    "udt_node": [("twinslam_msgs/msg/UplinkThroughput", "/device/uplink_throughput")],
}


#: well-formed CDR whose content is inconsistent: it passes any CDR check and must be refused
#: by the node's validation
INCONSISTENT = {
    "sensor_msgs/msg/Image": {"height": 4, "width": 3, "encoding": "mono8", "step": 3,
                              "data": np.zeros(6, np.uint8)},          # 6 bytes for 12 pixels
    "sensor_msgs/msg/CameraInfo": {},                                  # K all zero
    "twinslam_msgs/msg/UploadRequest": {"rate_mbps": float("nan")},
    "twinslam_msgs/msg/MapUpdate": {"keyframe_ids": np.array([1, 2], np.uint64)},  # no poses
    "twinslam_msgs/msg/FrameSummaries": {"rate_mbps": -1.0},
    "twinslam_msgs/msg/Keyframe": {"keypoints_xy": np.zeros(3, np.float32)},       # odd length
    "twinslam_msgs/msg/UplinkThroughput": {"achieved_mbps": float("nan")},
    "twinslam_msgs/msg/RateLatent": {"mu": np.zeros(2, np.float32),
                                     "sigma": np.ones(3, np.float32)},
    "twinslam_msgs/msg/RelocalisationRequest": {"keypoints_xy": np.ones(4, np.float32),
                                                "descriptors": np.zeros(40, np.uint8)},
    "twinslam_msgs/msg/Relocalisation": {"found": True,
                                         "pose": new("geometry_msgs/msg/Pose", orientation=new(
                                             "geometry_msgs/msg/Quaternion", w=2.0))},
}


def _hostile(type_name: str, rng: np.random.Generator) -> list[bytes]:
    """Truncations, random bytes, 4 GB lengths and bit flips of one type's sample, and an
    inconsistent message of that type."""
    good = _sample(type_name)
    out = [good[:n] for n in (8, 12, len(good) // 2, len(good) - 1)]
    out += [good[:8] + rng.integers(0, 256, n, dtype=np.uint8).tobytes() for n in (5, 64, 1000)]
    for at in range(8, len(good) - 3, 4):
        data = bytearray(good)
        data[at:at + 4] = b"\xff\xff\xff\xff"
        out.append(bytes(data))
        data = bytearray(good)
        data[at + int(rng.integers(0, 4))] ^= 1 << int(rng.integers(0, 8))
        out.append(bytes(data))
    return [*out, serialize_message(new(type_name, **INCONSISTENT[type_name]))]


@pytest.mark.slow
def test_running_nodes_survive_hostile_samples_and_still_answer(
        domain: Any, ros: RosSession, cyclone: Callable[[], Any]) -> None:
    """The real node processes, sent hostile samples over DDS on every topic they read by a
    raw Cyclone writer, log the rejections (each type, including its inconsistent message),
    stay up, and answer the next well-formed message; the edge's map survives."""
    from twinslam_msgs.msg import MapStats, RateLatent, UplinkThroughput, UploadRequest

    from device_tracker.messages import FrameRecord, frame_summaries_message

    procs = {name: domain.spawn(["-m", f"{name}.node"], forks=FORKS) for name in NODE_TOPICS}
    got: dict[str, list[Any]] = {"latent": [], "request": [], "throughput": [], "stats": []}
    node = ros.node
    node.create_subscription(RateLatent, "/udt/rate_latent", got["latent"].append, qos.PROTOCOL)
    node.create_subscription(UploadRequest, "/edge/upload_request", got["request"].append,
                             qos.PROTOCOL)
    node.create_subscription(UplinkThroughput, "/device/uplink_throughput",
                             got["throughput"].append, qos.PROTOCOL)
    node.create_subscription(MapStats, "/edge/map_stats", got["stats"].append, qos.PROTOCOL)
    good = {t: node.create_publisher(message_class(t), topic,
                                     qos.MAP if topic == "/edge/map_update" else qos.PROTOCOL)
            for topics in NODE_TOPICS.values() for t, topic in topics
            if t.startswith("twinslam_msgs")}
    dp = cyclone()
    raw = {(t, topic): cyclone_peer.RawWriter(dp, topic, message_class(t),
                                              transient_local=topic == "/edge/map_update")
           for topics in NODE_TOPICS.values() for t, topic in topics}
    # every node listens on all of its topics (the edge and the twin publish once warm): as
    # many readers matched on a topic as nodes read it, and this test's own — a storm sent
    # when only the first of them matched (the twin, loading torch, comes up last) would
    # never reach the others
    own = Counter(sub.topic_name for sub in node.subscriptions)
    readers = Counter((t, topic) for topics in NODE_TOPICS.values() for t, topic in topics)
    assert ros.spin_until(lambda: (all(w.matched() >= readers[t, topic] + own[topic]
                                       for (t, topic), w in raw.items())
                          and all(p.get_subscription_count() >= readers[t, p.topic_name]
                                  + own[p.topic_name] for t, p in good.items()))
                          or any(p.poll() is not None for p in procs.values()), 90.0)
    assert all(p.poll() is None for p in procs.values())
    frames = [FrameRecord(f, 0.1 * f, np.eye(4), True, np.arange(5, dtype=np.uint64) + f,
                          np.zeros(0, np.uint64), 900) for f in range(3)]
    summaries = good["twinslam_msgs/msg/FrameSummaries"]
    summaries.publish(frame_summaries_message(900, 40.0, 0, 0, frames, time.time()))
    assert ros.spin_until(lambda: any(m.slot == 900 for m in got["stats"]), 30.0), \
        "the edge answered no slot before the storm"
    before = next(m for m in got["stats"] if m.slot == 900)
    rng = np.random.default_rng(8)
    sent = 0
    for (type_name, _topic), writer in raw.items():
        for payload in _hostile(type_name, rng):
            writer.write(payload)
            sent += 1
            ros.spin_once(0.005)
    # the storm has arrived when every node logged a rejection of each of its types
    def not_rejected() -> list[tuple[str, str]]:
        return [(name, type_name) for name, topics in NODE_TOPICS.items()
                for type_name, _topic in topics
                if f"dropped a malformed {type_name}" not in domain.log(procs[name])]

    assert ros.spin_until(lambda: not not_rejected(), 60.0), \
        f"no rejection logged of {not_rejected()}; logs: " + "\n".join(
            f"--- {name}\n{domain.log(proc)[-1500:]}" for name, proc in procs.items())
    # well-formed messages after the storm: each node still answers
    good["twinslam_msgs/msg/UplinkThroughput"].publish(
        new("twinslam_msgs/msg/UplinkThroughput", slot=901, configured_rate_mbps=40.0,
            achieved_mbps=39.0, bytes_sent=2_000_000, duration_s=0.4, frames_sent=3))
    summaries.publish(frame_summaries_message(902, 40.0, 0, 0, frames, time.time()))
    good["twinslam_msgs/msg/UploadRequest"].publish(
        new("twinslam_msgs/msg/UploadRequest", slot=903, policy="lff",
            upload_frame_ids=np.array([5], np.uint64)))
    assert ros.spin_until(lambda: any(m.slot == 901 for m in got["latent"])
                          and any(m.slot == 902 for m in got["stats"])
                          and any(m.slot == 903 for m in got["throughput"]), 30.0), \
        {k: [m.slot for m in v][-4:] for k, v in got.items()}
    assert all(p.poll() is None for p in procs.values()), "a node died on hostile input"
    after = next(m for m in got["stats"] if m.slot == 902)
    assert after.map_size == before.map_size and after.map_points == before.map_points, \
        "the edge's map lost content to hostile input"
    rejected = {}
    for name, proc in procs.items():
        code, _out, err = domain.stop(proc)
        assert code == 0, err[-2000:]
        rejected[name] = err.count("dropped a malformed")
        for type_name, _topic in NODE_TOPICS[name]:
            assert f"dropped a malformed {type_name}" in err, f"{name}: {type_name}"
        assert "not CDR of the type" in err and "Traceback" not in err, name
    print(f"\nhostile samples: {sent} sent by a raw Cyclone writer; rejections the nodes "
          f"logged: {rejected}")


def test_a_security_enclave_that_cannot_be_had_is_refused_with_the_reason(domain: Any) -> None:
    """SROS2 security asked for (ROS_SECURITY_ENABLE, Enforce) where it cannot be had: the node
    says why and exits 2, instead of a traceback."""
    env = domain.env_for(None)
    env.update({"ROS_SECURITY_ENABLE": "true", "ROS_SECURITY_STRATEGY": "Enforce",
                "ROS_SECURITY_KEYSTORE": str(REPO / "no-such-keystore")})
    done = subprocess.run([sys.executable, "-m", "udt_node.node"], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "security" in done.stderr.lower() and "Traceback" not in done.stderr


def test_the_run_monitor_drops_a_map_update_cut_short_or_unreadable(ros: Any) -> None:
    """An edge killed while it wrote a map update leaves a sample cut short on the wire (8
    bytes, seen in a clean clone's edge-restart test): the run's monitor drops it as the
    nodes' checked subscriptions do, instead of raising into the executor and ending the run,
    and still reads the next whole update; so is one whose content no map has."""
    from rclpy.serialization import serialize_message

    from edge_mapper.messages import map_update_message
    from twinslam.live.monitor import PipelineMonitor
    from twinslam.slam.back_end.keyframe_map import KeyFrameMap

    monitor = PipelineMonitor(ros.node)
    info = {"received_timestamp": 0, "source_timestamp": 0}
    monitor._map(b"\x00\x01\x00\x00\x00\x00\x00\x00", info)
    assert monitor.record.maps == {} and monitor.record.downlink_bytes == 8
    whole = serialize_message(map_update_message(KeyFrameMap(), 3, 1, 0.0))
    monitor._map(whole, info)
    assert list(monitor.record.maps) == [3]
    # well-formed CDR whose frame correction is no rotation (a bit flipped into a NaN: what a
    # hostile writer sent a run once): dropped too, the run goes on
    broken = map_update_message(KeyFrameMap(), 4, 2, 0.0)
    broken.frame_correction.orientation.x = float("nan")
    monitor._map(serialize_message(broken), info)
    assert list(monitor.record.maps) == [3] and 4 not in monitor.record.first_map_versions
