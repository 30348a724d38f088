"""Receiving side of ``bench.dds``: records arrival time and header stamp of every image."""

from __future__ import annotations

import json
import sys
import time

import node_runtime


def main() -> int:
    node_runtime.init()
    node = node_runtime.Node("bench_receiver")
    latencies: list[float] = []
    seqs: list[int] = []

    def on_image(msg: object) -> None:
        now = time.time()
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        latencies.append(now - stamp)
        seqs.append(int(msg.header.frame_id))

    sub = node.create_subscription("sensor_msgs/msg/Image", "bench/image", on_image,
                                   node_runtime.QoSProfile(depth=30))
    print(json.dumps({"event": "ready"}), flush=True)
    node_runtime.run(node)
    print(json.dumps({"event": "result", "latencies": latencies, "seqs": seqs,
                      "rejected": sub.rejected}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
