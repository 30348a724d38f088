"""The device's uplink shaped by the kernel: Linux ``tc`` on the uplink interface.

The alternative to :class:`~twinslam.uplink.shaper.UplinkShaper` (``shaper:=tc``): instead
of pacing payloads in the process, each slot sets a token bucket filter (``tbf``) of rate d_k
as the root qdisc of the device's uplink interface, optionally with ``netem`` delay and loss
below it, and the device writes its keyframes as fast as DDS lets it. The kernel holds the
packets back; the UDP socket's send buffer fills and blocks the writer, so Fast DDS's reliable
protocol (RTPS heartbeats and acknowledgements) and the link's rate decide when the bytes
arrive, as on a real uplink.

What a slot achieved is measured, not assumed: the bytes the interface transmitted between
``start_slot`` and the moment every reliable reader acknowledged the slot's keyframes (the
``flush`` callable), over that time. Those are link bytes — RTPS, UDP, IP and Ethernet headers
included, ~13 % above the keyframes' own bytes (BENCHMARKS.md) — the rate the link delivered.

Changing a qdisc needs CAP_NET_ADMIN in the interface's network namespace: a device node run
as root inside its host (or with that capability) can; elsewhere ``start`` fails with the
reason.
"""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from twinslam.uplink.shaper import ShaperError, SlotThroughput, UplinkShaper, check_rate

#: bucket depth: well above rate / HZ at 80 Mbit/s, small against a slot's megabytes
BURST = "64kb"
#: how long a packet may wait in the bucket's queue: rate × latency (2.5 MB at 40 Mbit/s) is
#: more than the UDP socket's send buffer holds, so the writer blocks before the queue drops
LATENCY = "500ms"


@dataclass(frozen=True)
class NetemConfig:
    """Extra impairment below the bucket (``tc netem``): one-way delay and random loss."""

    delay_ms: float = 0.0
    loss_percent: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delay_ms) and self.delay_ms >= 0):
            raise ShaperError(f"netem delay must be >= 0 ms, got {self.delay_ms}")
        if not (math.isfinite(self.loss_percent) and 0 <= self.loss_percent < 100):
            raise ShaperError(f"netem loss must be in [0, 100) %, got {self.loss_percent}")

    @property
    def active(self) -> bool:
        return self.delay_ms > 0 or self.loss_percent > 0


def interface_tx_bytes(interface: str, proc_net_dev: Path = Path("/proc/net/dev")) -> int:
    """Bytes ``interface`` has transmitted, as this process's network namespace counts them."""
    for line in proc_net_dev.read_text().splitlines()[2:]:
        name, _, fields = line.partition(":")
        if name.strip() == interface:
            return int(fields.split()[8])
    raise ShaperError(f"no interface {interface!r} in this host's {proc_net_dev}")


def run_tc(*args: str) -> None:
    try:
        done = subprocess.run(["tc", *args], capture_output=True, text=True)
    except FileNotFoundError:
        raise ShaperError("`tc` (iproute2) is not installed on this host: the tc shaper needs "
                          "it; use shaper:=token_bucket") from None
    if done.returncode != 0:
        raise ShaperError(f"`tc {' '.join(args)}` failed: {done.stderr.strip()} (the tc shaper "
                          "needs CAP_NET_ADMIN on the uplink interface: run the device node as "
                          "root in its host, or use shaper:=token_bucket)")


class TcShaper:
    """``tbf`` of the slot's rate on ``interface``; the same slot interface as UplinkShaper."""

    def __init__(self, interface: str, netem: NetemConfig | None = None,
                 flush: Callable[[], object] = lambda: None,
                 tc: Callable[..., None] = run_tc,
                 tx_bytes: Callable[[], int] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.interface = interface
        self.netem = netem or NetemConfig()
        self._flush, self._tc, self._clock = flush, tc, clock
        self._tx_bytes = tx_bytes or (lambda: interface_tx_bytes(interface))
        self._rate_mbps = 0.0
        self._installed = False
        self._slot: int | None = None
        self._state = 0
        self._start = 0.0
        self._start_bytes = 0
        self._frames = 0

    @property
    def rate_mbps(self) -> float:
        return self._rate_mbps

    def _set_rate(self, rate_mbps: float) -> None:
        verb = "change" if self._installed else "replace"
        self._tc("qdisc", verb, "dev", self.interface, "root", "handle", "1:", "tbf", "rate",
                 f"{rate_mbps * 1e3:.0f}kbit", "burst", BURST, "latency", LATENCY)
        if not self._installed and self.netem.active:
            self._tc("qdisc", "replace", "dev", self.interface, "parent", "1:1", "handle", "10:",
                     "netem", "delay", f"{self.netem.delay_ms:g}ms", "loss",
                     f"{self.netem.loss_percent:g}%")
        self._installed = True
        self._rate_mbps = rate_mbps

    def start(self, rate_mbps: float) -> None:
        """Install the qdisc before the first slot (fails early without CAP_NET_ADMIN)."""
        check_rate(rate_mbps, "start")
        self._tx_bytes()                         # the interface exists in this host
        self._set_rate(rate_mbps)

    def start_slot(self, slot: int, rate_mbps: float, rate_state: int = 0) -> None:
        check_rate(rate_mbps, slot)
        if rate_mbps != self._rate_mbps or not self._installed:
            self._set_rate(rate_mbps)
        self._slot, self._state, self._frames = slot, rate_state, 0
        self._start = self._clock()
        self._start_bytes = self._tx_bytes()

    def send(self, n_bytes: int, deliver: Callable[[], object]) -> float:
        """Write now; the kernel paces the packets (``n_bytes`` is the caller's estimate and
        not used: the interface counts what really went out)."""
        if self._slot is None:
            raise ShaperError("no slot started: call start_slot(slot, rate) first")
        called = self._clock()
        deliver()
        self._frames += 1
        return self._clock() - called

    def carry(self, n_bytes: int, deliver: Callable[[], object], rate_mbps: float) -> float:
        """Write a payload besides the slot's keyframes now: the kernel paces it at the
        installed rate with everything else the device sends (``n_bytes`` and ``rate_mbps``
        are not used)."""
        called = self._clock()
        deliver()
        return self._clock() - called

    def end_slot(self) -> SlotThroughput:
        """Wait until the slot's keyframes are acknowledged, then measure."""
        if self._slot is None:
            raise ShaperError("no slot started")
        if self._frames:
            self._flush()
        sent = self._tx_bytes() - self._start_bytes
        return SlotThroughput(self._slot, self._rate_mbps, self._state,
                              sent if self._frames else 0, self._clock() - self._start,
                              self._frames)

    def close(self) -> None:
        """Remove the qdisc: the interface is left as it was found."""
        if self._installed:
            try:
                self._tc("qdisc", "del", "dev", self.interface, "root")
            except ShaperError:
                pass
            self._installed = False


SHAPERS = ("token_bucket", "tc")


def make_shaper(kind: str, initial_rate_mbps: float, interface: str = "eth0",
                netem: NetemConfig | None = None,
                flush: Callable[[], object] = lambda: None) -> UplinkShaper | TcShaper:
    """The uplink shaper a device is configured with: ``token_bucket`` paces in the process,
    ``tc`` installs a tbf on ``interface`` at ``initial_rate_mbps`` (CAP_NET_ADMIN).
    ValueError for another kind, ShaperError when tc cannot be set up."""
    if kind == "token_bucket":
        return UplinkShaper()
    if kind != "tc":
        raise ValueError(f"shaper must be one of {', '.join(SHAPERS)}, got {kind!r}")
    shaper = TcShaper(interface, netem or NetemConfig(), flush=flush)
    shaper.start(initial_rate_mbps)
    return shaper
