"""Uplink benchmark: the device's uplink shaped by ``tc`` across network namespaces.

The pipeline runs on three hosts (``twinslam.hosts.netns``) with ``shaper:=tc`` and real frames
as keyframes (``upload_image:=true``); per slot it prints the rate d_k the ``tbf`` was set to,
what the device measured on its interface until its keyframes were acknowledged, and the bytes
the switch received from the device's cable over the whole run.

    sudo python -m bench.uplink [SEQUENCE] [--frames 600]

Needs root and iproute2.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys

from bench.paths import SEVEN_SCENES
from twinslam.hosts.netns import NetnsHosts, unavailable_reason
from twinslam.live.launcher import LaunchConfig, Launcher, tc_uplink_params

FRAME_MBIT = 640 * 480 * 3 * 8 / 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", nargs="?",
                        default=str(SEVEN_SCENES),
                        help="RGB-D sequence folder (default: the bundled 7-Scenes sample)")
    parser.add_argument("--frames", type=int, default=600, help="frames to play")
    args = parser.parse_args()
    why = unavailable_reason()
    if why:
        print(f"bench.uplink: {why}", file=sys.stderr)
        return 2
    with NetnsHosts(prefix="bench-") as hosts:
        before = hosts.port_bytes("device")
        launcher = Launcher(hosts, LaunchConfig(args.sequence, "adapt", args.frames,
                                                extra=tc_uplink_params(FRAME_MBIT)), echo=None)
        report = launcher.run()
        crossed = hosts.port_bytes("device") - before
    record = launcher.record
    assert record is not None
    print(f"machine: {platform.processor() or platform.machine()}, {platform.system()} "
          f"{platform.release()}; {args.frames} frames of {args.sequence}")
    ratios: dict[int, list[float]] = {}
    print(f"{'slot':>4} {'frames':>6} {'MB':>6} {'tbf Mbit/s':>10} {'measured':>9} {'ratio':>6}"
          f" {'s':>5}")
    for slot, t in sorted(record.throughput.items()):
        if not t.frames_sent:
            continue
        ratio = t.achieved_mbps / t.configured_rate_mbps
        ratios.setdefault(round(t.configured_rate_mbps), []).append(ratio)
        print(f"{slot:>4} {t.frames_sent:>6} {t.bytes_sent / 1e6:>6.2f} "
              f"{t.configured_rate_mbps:>10.0f} {t.achieved_mbps:>9.1f} {ratio:>6.1%} "
              f"{t.duration_s:>5.2f}")
    for rate, rs in sorted(ratios.items()):
        print(f"{rate} Mbit/s: measured/configured median {statistics.median(rs):.1%}, "
              f"range {min(rs):.1%}–{max(rs):.1%} over {len(rs)} slots")
    sent = sum(t.bytes_sent for t in record.throughput.values())
    print(f"device link bytes in upload windows {sent / 1e6:.1f} MB; switch received "
          f"{crossed / 1e6:.1f} MB from the device over the run; {report.frames_uploaded} "
          f"frames of {FRAME_MBIT:.2f} Mbit = {report.frames_uploaded * FRAME_MBIT / 8:.1f} MB "
          "of pixels")
    print(f"mean υ {report.mean_uncertainty:.1f}, ATE {report.ate_m:.3f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
