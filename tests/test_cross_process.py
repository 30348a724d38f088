"""Nodes as separate OS processes on a private loopback domain: delivery, discovery info,
remapping and parameters, malformed input, and clean shutdown on signals."""

from __future__ import annotations

import hashlib
import signal
import time

import cyclonedds._clayer as _clayer
import numpy as np
import pytest
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

import node_runtime
from msg_schemas import new, typestore
from msg_schemas.dds_types import dds_type
from msg_schemas.registry import type_hash
from node_runtime.context import DISCOVERY_TOPIC, DISCOVERY_TYPE, get_context
from node_runtime.graph import GRAPH_READER_QOS, GraphMonitor
from node_runtime.loopback import JsonLines, LoopbackDomain

LISTENER = ["-m", "tests.nodes.listener"]


def _image() -> object:
    rng = np.random.default_rng(1)
    img = new("sensor_msgs/msg/Image", height=480, width=640, encoding="rgb8", step=1920,
              data=rng.integers(0, 255, 640 * 480 * 3, dtype=np.uint8))
    img.header.frame_id = "camera"
    img.header.stamp.sec = 12
    return img


def _pose() -> object:
    msg = new("geometry_msgs/msg/PoseStamped")
    msg.header.frame_id = "map"
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 1.0, -2.0, 0.5
    return msg


def _summaries() -> object:
    frame = new("twinslam_msgs/msg/FrameSummary", frame_id=7, tracked=True, pose=_pose().pose,
                map_point_ids=np.array([3, 5, 8], dtype=np.uint64))
    return new("twinslam_msgs/msg/FrameSummaries", slot=2, rate_mbps=55.0, frames=[frame])


def _sha(msg: object) -> str:
    return hashlib.sha256(bytes(typestore().serialize_cdr(msg, msg.__msgtype__))).hexdigest()


def _publish_until_received(executor: node_runtime.SingleThreadedExecutor, pub, msg,
                            lines: JsonLines, timeout: float) -> tuple[dict, float]:
    """Publish every 50 ms until the other process reports a message; bounded by timeout."""
    start = time.monotonic()
    deadline = start + timeout
    while time.monotonic() < deadline:
        pub.publish(msg)
        try:
            return lines.next("msg", timeout=0.05), time.monotonic() - start
        except TimeoutError:
            executor.spin_once(0.0)
    raise TimeoutError(f"nothing delivered within {timeout} s")


@pytest.mark.parametrize(("type_name", "factory", "qos"), [
    ("sensor_msgs/msg/Image", _image, "sensor_data"),
    ("geometry_msgs/msg/PoseStamped", _pose, "default"),
    ("twinslam_msgs/msg/FrameSummaries", _summaries, "default"),
])
def test_two_processes_exchange_messages_within_3_s(domain: LoopbackDomain, ros, type_name,
                                                    factory, qos) -> None:
    proc = domain.spawn([*LISTENER, "--ros-args", "-p", f"type:={type_name}", "-p", f"qos:={qos}"])
    lines = JsonLines(proc)
    lines.next("ready", timeout=30)
    node = node_runtime.Node("talker")
    profile = node_runtime.SENSOR_DATA if qos == "sensor_data" else node_runtime.DEFAULT
    pub = node.create_publisher(type_name, "chatter", profile)
    msg = factory()
    got, elapsed = _publish_until_received(ros, pub, msg, lines, timeout=3.0)
    print(f"{type_name}: discovery + first delivery in {elapsed * 1000:.0f} ms")
    assert got["sha256"] == _sha(msg)
    assert elapsed < 3.0


def test_discovery_info_decodes_with_rosbags_and_lists_the_node(domain: LoopbackDomain,
                                                                 ros) -> None:
    proc = domain.spawn([*LISTENER, "--ros-args", "-r", "__node:=ears", "-r", "__ns:=/robot"])
    ready = JsonLines(proc).next("ready", timeout=30)
    participant = get_context().participant
    reader = DataReader(participant, Topic(participant, DISCOVERY_TOPIC, dds_type(DISCOVERY_TYPE)),
                        qos=GRAPH_READER_QOS.to_dds(type_hash(DISCOVERY_TYPE)))
    store = typestore()
    mask = SampleState.Any | ViewState.Any | InstanceState.Any
    deadline = time.monotonic() + 5
    found = None
    while found is None and time.monotonic() < deadline:
        ret = _clayer.ddspy_take(reader._ref, mask, 16)
        for data, info in ret if not isinstance(ret, int) else []:
            if not info.valid_data:
                continue
            msg = store.deserialize_cdr(bytes(data), DISCOVERY_TYPE)  # the reference decoder
            for node in msg.node_entities_info_seq:
                if node.node_name == "ears":
                    found = (msg, node)
        time.sleep(0.05)
    assert found is not None, "no ros_discovery_info sample announced node 'ears'"
    msg, node = found
    assert node.node_namespace == "/robot"
    assert bytes(msg.gid.data).hex() == ready["participant_gid"]
    assert [bytes(g.data).hex() for g in node.reader_gid_seq] == ready["reader_gids"]
    # The graph monitor (`twinslam nodes`) sees the same node.
    monitor = GraphMonitor(participant)
    assert monitor.wait_for({"/robot/ears"}, timeout=5)


def test_remapping_namespace_and_parameters_across_processes(domain: LoopbackDomain, ros,
                                                             tmp_path) -> None:
    params = tmp_path / "listener.yaml"
    params.write_text("/robot/ears:\n  ros__parameters:\n    type: geometry_msgs/msg/PoseStamped\n"
                      "    extra: from-file\n")
    proc = domain.spawn([*LISTENER, "--ros-args", "-r", "__node:=ears", "-r", "__ns:=/robot",
                         "-r", "chatter:=/remapped/pose", "--params-file", str(params),
                         "-p", "extra:=from-cli"])
    lines = JsonLines(proc)
    ready = lines.next("ready", timeout=30)
    assert (ready["name"], ready["namespace"]) == ("ears", "/robot")
    assert ready["topic"] == "/remapped/pose"  # the remap rule, not /robot/chatter
    assert ready["extra"] == "from-cli"        # -p given after --params-file wins
    node = node_runtime.Node("talker")
    pub = node.create_publisher("geometry_msgs/msg/PoseStamped", "/remapped/pose")
    msg = _pose()
    got, _ = _publish_until_received(ros, pub, msg, lines, timeout=3.0)
    assert got["type"] == "geometry_msgs/msg/PoseStamped"  # the type came from the params file
    assert got["sha256"] == _sha(msg)


def test_malformed_payload_is_logged_dropped_and_the_next_one_arrives(domain: LoopbackDomain,
                                                                      ros) -> None:
    proc = domain.spawn([*LISTENER, "--ros-args", "-p", "type:=sensor_msgs/msg/Image"])
    lines = JsonLines(proc)
    lines.next("ready", timeout=30)
    node = node_runtime.Node("talker")
    pub = node.create_publisher("sensor_msgs/msg/Image", "chatter")
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, 5)
    truncated = _image()
    truncated.data = truncated.data[:1000]  # 1000 bytes where height x step says 921600
    pub.publish(truncated)
    good = _image()
    pub.publish(good)
    got = lines.next("msg", timeout=3)
    assert got["sha256"] == _sha(good)
    assert proc.poll() is None, "the listener died on a malformed message"
    code, _out, err = domain.stop(proc)
    assert code == 0
    assert "dropped a malformed sensor_msgs/msg/Image" in err and "truncated" in err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_a_node_cleanly_within_2_s(domain: LoopbackDomain, sig) -> None:
    proc = domain.spawn(["-m", "edge_mapper.node"])
    proc_lines = proc.stderr
    assert proc_lines is not None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # wait until the node has started (its ready line)
        line = proc_lines.readline()
        if "listening on" in line or not line:
            break
    start = time.monotonic()
    proc.send_signal(sig)
    code = proc.wait(timeout=10)
    elapsed = time.monotonic() - start
    print(f"{sig.name}: exited {code} in {elapsed * 1000:.0f} ms")
    assert code == 0
    assert elapsed < 2.0


def test_graph_monitor_sees_every_participant_of_the_domain(domain: LoopbackDomain, ros) -> None:
    """ros_discovery_info is keyless: one shallow reader would keep only the newest node."""
    names = ["alpha", "beta", "gamma"]
    for name in names:
        domain.spawn([*LISTENER, "--ros-args", "-r", f"__node:={name}"])
    monitor = GraphMonitor(get_context().participant)
    assert monitor.wait_for({f"/{n}" for n in names}, timeout=30)
