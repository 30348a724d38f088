"""DDS image benchmark: 640x480 rgb8 at 30 Hz for 10 s between two processes (issue #2).

Reports delivered %, one-way latency median/p99 (header stamp → subscriber callback, same host
clock) over RELIABLE QoS on a private loopback domain, and the in-process serialise+deserialise
cost per MB of our codec next to Cyclone's own Python serialiser for the same type.

    python -m bench.dds [--seconds 10] [--rate 30]
"""

from __future__ import annotations

import argparse
import json
import platform
import signal
import time

import numpy as np

import node_runtime
from msg_schemas import cdr, new
from msg_schemas.dds_types import dds_type
from node_runtime.loopback import JsonLines, LoopbackDomain


def codec_ms_per_mb(repeats: int = 50) -> tuple[float, float]:
    """Round trip (encode + decode) ms per MB: ours, and Cyclone's generic Python path."""
    img = new("sensor_msgs/msg/Image", height=480, width=640, encoding="rgb8", step=1920,
              data=np.random.default_rng(0).integers(0, 255, 921600, dtype=np.uint8))
    size_mb = len(cdr.serialize(img)) / 1e6
    start = time.perf_counter()
    for _ in range(repeats):
        cdr.deserialize(cdr.serialize(img), "sensor_msgs/msg/Image")
    ours = (time.perf_counter() - start) / repeats * 1000 / size_mb
    T = dds_type("sensor_msgs/msg/Image")
    stamp = dds_type("builtin_interfaces/msg/Time")(sec=0, nanosec=0)
    hdr = dds_type("std_msgs/msg/Header")(stamp=stamp, frame_id="")
    sample = T(header=hdr, height=480, width=640, encoding="rgb8", is_bigendian=0, step=1920,
               data=img.data.tolist())
    start = time.perf_counter()
    reps = 3
    for _ in range(reps):
        T.deserialize(sample.serialize(use_version_2=False))
    cyclone = (time.perf_counter() - start) / reps * 1000 / size_mb
    return ours, cyclone


def run(seconds: float, rate: float) -> dict:
    with LoopbackDomain() as dom:
        dom.activate()
        proc = dom.spawn(["-m", "bench.dds_receiver"])
        lines = JsonLines(proc)
        lines.next("ready", timeout=60)
        node_runtime.init(args=["bench"], install_signal_handlers=False)
        node = node_runtime.Node("bench_sender")
        pub = node.create_publisher("sensor_msgs/msg/Image", "bench/image",
                                    node_runtime.QoSProfile(depth=30))
        executor = node_runtime.SingleThreadedExecutor()
        executor.add_node(node)
        if not executor.spin_until(lambda: pub.get_subscription_count() > 0, 10):
            raise RuntimeError("receiver never matched")
        time.sleep(0.5)
        pixels = np.random.default_rng(0).integers(0, 255, 921600, dtype=np.uint8)
        count = int(seconds * rate)
        t0 = time.monotonic()
        for i in range(count):
            target = t0 + i / rate
            while (delay := target - time.monotonic()) > 0:
                time.sleep(delay)
            now = time.time()
            img = new("sensor_msgs/msg/Image", height=480, width=640, encoding="rgb8",
                      step=1920, data=pixels)
            img.header.stamp.sec, img.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
            img.header.frame_id = str(i)
            pub.publish(img)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        result = lines.next("result", timeout=30)
        proc.wait(timeout=10)
        node.destroy_node()
        node_runtime.shutdown()
    lat = np.array(result["latencies"]) * 1000
    return {"sent": count, "delivered": len(set(result["seqs"])),
            "delivered_pct": 100.0 * len(set(result["seqs"])) / count,
            "latency_median_ms": float(np.median(lat)) if lat.size else float("nan"),
            "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=30.0)
    args = parser.parse_args()
    ours, cyclone = codec_ms_per_mb()
    print(f"machine: {platform.node()} {platform.machine()} {platform.processor() or ''} "
          f"python {platform.python_version()}")
    print(f"codec round trip, 640x480 rgb8: ours {ours:.3f} ms/MB, "
          f"cyclonedds generic {cyclone:.1f} ms/MB")
    res = run(args.seconds, args.rate)
    print(json.dumps(res))
    print(f"images {res['delivered']}/{res['sent']} delivered ({res['delivered_pct']:.1f} %), "
          f"latency median {res['latency_median_ms']:.2f} ms, p99 {res['latency_p99_ms']:.2f} ms")


if __name__ == "__main__":
    main()
