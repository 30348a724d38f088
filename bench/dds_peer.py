"""The two processes of ``bench.dds``: ``receive`` records the arrival time and header stamp of
every image (through the nodes' own decoding and validation path,
:class:`~twinslam.node_runtime.checked_subscription.CheckedSubscription`); ``send``
publishes 640×480 rgb8 images at a fixed rate, stamped with the wall clock just before each publish.

    python -m bench.dds_peer receive|send --qos reliable|sensor_data [--seconds S --rate R]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import rclpy
import rclpy.executors
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from msg_schemas import new
from twinslam.node_runtime.acks import wait_for_acks
from twinslam.node_runtime.allocator import keep_freed_memory
from twinslam.node_runtime.checked_subscription import CheckedSubscription

TOPIC = "bench/image"


def profile(name: str) -> QoSProfile:
    """Depth 30 (one second of frames), reliable or best effort (sensor-data)."""
    reliability = (ReliabilityPolicy.RELIABLE if name == "reliable"
                   else ReliabilityPolicy.BEST_EFFORT)
    return QoSProfile(depth=30, reliability=reliability)


def receive(qos: QoSProfile, events_executor: bool) -> None:
    node = Node("bench_receiver")
    latencies: list[float] = []
    seqs: list[int] = []

    def on_image(msg: Image) -> None:
        now = time.time()
        latencies.append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))
        seqs.append(int(msg.header.frame_id))

    sub = CheckedSubscription(node, Image, TOPIC, on_image, qos)
    print(json.dumps({"event": "ready"}), flush=True)
    executor = (EventsExecutor() if events_executor
                else rclpy.executors.SingleThreadedExecutor())
    executor.add_node(node)
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    print(json.dumps({"event": "result", "latencies": latencies, "seqs": seqs,
                      "rejected": sub.rejected}), flush=True)


def send(qos: QoSProfile, seconds: float, rate: float) -> None:
    node = Node("bench_sender")
    pub = node.create_publisher(Image, TOPIC, qos)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    if pub.get_subscription_count() == 0:
        raise SystemExit("bench_sender: the receiver never matched")
    time.sleep(1.0)                  # discovery settles both ways
    pixels = np.random.default_rng(0).integers(0, 255, 921600, dtype=np.uint8)
    count = int(seconds * rate)
    t0 = time.monotonic()
    for i in range(count):
        while (delay := t0 + i / rate - time.monotonic()) > 0:
            time.sleep(delay)
        img = new(Image, height=480, width=640, encoding="rgb8", step=1920, data=pixels)
        img.header.frame_id = str(i)
        now = time.time()
        img.header.stamp.sec, img.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
        pub.publish(img)
    wait_for_acks(pub, 2.0)
    print(json.dumps({"event": "sent", "count": count}), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("role", choices=["receive", "send"], help="which end of the link")
    parser.add_argument("--qos", choices=["reliable", "sensor_data"], default="reliable",
                        help="reliable, or best effort (sensor data)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of images (send)")
    parser.add_argument("--rate", type=float, default=30.0, help="images per second (send)")
    parser.add_argument("--as-nodes", action="store_true",
                        help="set the process up as twinslam's nodes are "
                        "(twinslam.node_runtime.node_main): the C++ EventsExecutor and "
                        "freed memory kept (twinslam.node_runtime.allocator); "
                        "without it, rclpy's SingleThreadedExecutor and glibc's defaults")
    args = parser.parse_args()
    if args.as_nodes:
        keep_freed_memory()
    rclpy.init()
    try:
        if args.role == "receive":
            receive(profile(args.qos), args.as_nodes)
        else:
            send(profile(args.qos), args.seconds, args.rate)
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
