"""DDS image benchmark through rclpy: 640×480 rgb8 at 30 Hz for 10 s between two processes.

For RELIABLE and sensor-data (best effort) QoS, each as the nodes run (the project's Fast DDS
profile ``config/fastdds.xml``, processes set up as ``twinslam.node_runtime.node_main`` does:
the C++ EventsExecutor, freed memory kept), with the profile alone (rclpy's SingleThreadedExecutor,
glibc's defaults), and with all defaults, side by side in one run: images
delivered and one-way latency median / p99 (header stamp → the receiver's callback, after the
nodes' own decoding and validation; one host clock). Each configuration runs a fresh sender and
receiver process on a private domain (Fast DDS reads its profile once per process).

    python -m bench.dds [--seconds 10] [--rate 30]
"""

from __future__ import annotations

import argparse
import json
import platform
import signal
from typing import Any

import numpy as np

from twinslam.hosts.loopback import JsonLines, LoopbackDomain


class _Domain(LoopbackDomain):
    """A loopback domain whose processes run with or without the project's profile."""

    def __init__(self, with_profile: bool) -> None:
        super().__init__()
        self.with_profile = with_profile

    @property
    def env(self) -> dict[str, str]:
        env = super().env
        if not self.with_profile:
            env.pop("FASTRTPS_DEFAULT_PROFILES_FILE")
        return env


def run(qos: str, with_profile: bool, as_nodes: bool, seconds: float, rate: float
        ) -> dict[str, Any]:
    setup = ["--as-nodes"] if as_nodes else []
    with _Domain(with_profile) as dom:
        receiver = dom.spawn(["-m", "bench.dds_peer", "receive", "--qos", qos, *setup])
        lines = JsonLines(receiver)
        lines.next("ready", timeout=60)
        sender = dom.spawn(["-m", "bench.dds_peer", "send", "--qos", qos, "--seconds",
                            str(seconds), "--rate", str(rate), *setup])
        sent = JsonLines(sender).next("sent", timeout=seconds + 90)["count"]
        receiver.send_signal(signal.SIGINT)
        result = lines.next("result", timeout=30)
    lat = np.array(result["latencies"]) * 1000
    delivered = len(set(result["seqs"]))
    return {"qos": qos, "profile": "twinslam" if with_profile else "Fast DDS defaults",
            "process": "as nodes" if as_nodes else "rclpy defaults",
            "sent": sent, "delivered": delivered, "delivered_pct": 100.0 * delivered / sent,
            "latency_median_ms": float(np.median(lat)) if lat.size else float("nan"),
            "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan"),
            "rejected": result["rejected"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of images")
    parser.add_argument("--rate", type=float, default=30.0, help="images per second")
    args = parser.parse_args()
    print(f"machine: {platform.node()} {platform.machine()} {platform.processor() or ''} "
          f"python {platform.python_version()}; 640x480 rgb8 at {args.rate:g} Hz for "
          f"{args.seconds:g} s, rclpy + rmw_fastrtps_cpp", flush=True)
    rows = []
    for qos in ("reliable", "sensor_data"):
        for with_profile, as_nodes in ((True, True), (True, False), (False, False)):
            res = run(qos, with_profile, as_nodes, args.seconds, args.rate)
            rows.append(res)
            print(json.dumps(res), flush=True)
    print(f"\n{'QoS':<12} {'profile':<18} {'process':<15} {'delivered':>14} {'median ms':>10} "
          f"{'p99 ms':>8}")
    for r in rows:
        print(f"{r['qos']:<12} {r['profile']:<18} {r['process']:<15} "
              f"{r['delivered']:>5}/{r['sent']:<4} "
              f"{r['delivered_pct']:5.1f}% {r['latency_median_ms']:>9.2f} "
              f"{r['latency_p99_ms']:>8.2f}")


if __name__ == "__main__":
    main()
