"""The device's uplink as a link of the slot's rate d_k (paper §III-C).

On loopback or a LAN, DDS delivers a 5 Mbit keyframe in milliseconds; the paper's uplink takes
α / d_k seconds for it. The shaper makes the bytes take that time: it models the uplink as one
serial link of the configured rate and releases a payload only when its last bit would have
arrived — a token bucket of zero burst whose debt is the link's backlog. So every upload takes
at least bytes / d_k seconds after the link is free, uploads queue behind each other, and the
throughput a slot achieves is what the rate allows, never more.

The rate changes at slot boundaries (``start_slot``); a payload's transfer time is fixed when
``send`` is called, at the rate of that moment. ``send`` blocks its caller (the device's upload
thread). The clock and sleep are injectable, so tests can run the link on virtual time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass


class ShaperError(ValueError):
    """A rate or payload the link cannot carry (non-finite, negative, zero rate)."""


@dataclass(frozen=True)
class SlotThroughput:
    """What the uplink carried in one slot (the fields of ``UplinkThroughput``)."""

    slot: int
    configured_rate_mbps: float
    rate_state: int
    bytes_sent: int
    duration_s: float
    frames_sent: int
    #: relocalisation requests the link carried since the previous slot's report (bytes)
    request_bytes: int = 0

    @property
    def achieved_mbps(self) -> float:
        return self.bytes_sent * 8 / self.duration_s / 1e6 if self.duration_s > 0 else 0.0


def check_rate(rate_mbps: float, slot: object) -> None:
    """A slot's uplink rate must be a finite, positive Mbit/s (both shapers refuse others)."""
    if not math.isfinite(rate_mbps) or rate_mbps <= 0:
        raise ShaperError(f"slot {slot}: uplink rate must be finite and > 0 Mbit/s, got "
                          f"{rate_mbps}")


def _seconds(n_bytes: int, rate_bps: float) -> float:
    """How long ``n_bytes`` occupy a link of ``rate_bps`` bit/s."""
    if n_bytes < 0:
        raise ShaperError(f"payload size must be >= 0 bytes, got {n_bytes}")
    return n_bytes * 8 / rate_bps


class UplinkShaper:
    """Serialises payloads at the current slot's rate; ``send`` blocks until delivery."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self._clock, self._sleep = clock, sleep
        self._rate_bps = 0.0
        self._free_at = -math.inf          # when the link finishes its current backlog
        self._slot: int | None = None
        self._state = 0
        self._slot_start = 0.0
        self._bytes = 0
        self._frames = 0

    @property
    def rate_mbps(self) -> float:
        return self._rate_bps / 1e6

    def start_slot(self, slot: int, rate_mbps: float, rate_state: int = 0) -> None:
        """Begin slot ``slot`` at ``rate_mbps`` (Mbit/s); the previous slot's figures are
        dropped unless ``end_slot`` collected them."""
        check_rate(rate_mbps, slot)
        self._rate_bps = rate_mbps * 1e6
        self._slot, self._state = slot, rate_state
        self._slot_start = self._clock()
        self._bytes = self._frames = 0

    def transfer_time(self, n_bytes: int) -> float:
        """Seconds ``n_bytes`` occupy the link at the current rate."""
        if self._slot is None:
            raise ShaperError("no slot started: call start_slot(slot, rate) first")
        return _seconds(n_bytes, self._rate_bps)

    def send(self, n_bytes: int, deliver: Callable[[], object]) -> float:
        """Occupy the link for ``n_bytes``, then call ``deliver`` (which writes the message);
        returns the seconds from the call to delivery (queueing + transfer)."""
        waited = self._occupy(self.transfer_time(n_bytes), deliver)
        self._bytes += n_bytes
        self._frames += 1
        return waited

    def carry(self, n_bytes: int, deliver: Callable[[], object], rate_mbps: float) -> float:
        """A payload besides the slot's keyframes (a lost device's relocalisation request): it
        queues on the link with them at ``rate_mbps`` (the rate of the moment, which the slot
        may not have started with yet) and delays what follows as a keyframe would, but is not
        counted in the slot's keyframe throughput."""
        check_rate(rate_mbps, "carried payload")
        return self._occupy(_seconds(n_bytes, rate_mbps * 1e6), deliver)

    def _occupy(self, duration: float, deliver: Callable[[], object]) -> float:
        """Hold the link ``duration`` seconds after its backlog, then ``deliver``."""
        called = self._clock()
        done = max(called, self._free_at) + duration
        self._free_at = done
        while (wait := done - self._clock()) > 0:
            self._sleep(wait)
        deliver()
        return self._clock() - called

    def end_slot(self) -> SlotThroughput:
        """The slot's figures: bytes and frames delivered since ``start_slot``, over the slot's
        wall duration so far."""
        if self._slot is None:
            raise ShaperError("no slot started")
        return SlotThroughput(self._slot, self.rate_mbps, self._state, self._bytes,
                              self._clock() - self._slot_start, self._frames)
