"""The device's upload worker, without DDS: each slot's requested keyframes through the uplink
shaper on a thread of its own, so tracking never waits for the link (docs/architecture.md §1 step
4) — and, between them, whatever else the device sends up (a lost device's relocalisation
requests: :meth:`UplinkSender.carry`), queued on the same link so that it costs uplink time as
a keyframe does and is counted in the next slot's report.

For every ``UploadRequest`` the worker encodes the frames first (so the link never waits for
the CPU), starts the shaper's slot at the rate the device drew for it, sends each frame — the
link is occupied for the frame's charged size at that rate — and reports the slot's
throughput. A write that fails (a reliable writer whose readers stopped acknowledging times out
after its max blocking time) is retried until ``retry_s`` has passed, then given up with an
error: the slot goes on. Clock and sleep are injected for tests.
"""

from __future__ import annotations

import functools
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol

from twinslam.uplink.shaper import SlotThroughput

#: (frame id, serialized bytes, bytes the uplink is charged) of a frame to send
Encoded = tuple[int, bytes, int]


class Shaper(Protocol):
    def start_slot(self, slot: int, rate_mbps: float, rate_state: int = 0) -> None: ...

    def send(self, n_bytes: int, deliver: Callable[[], object]) -> float: ...

    def carry(self, n_bytes: int, deliver: Callable[[], object], rate_mbps: float) -> float: ...

    def end_slot(self) -> SlotThroughput: ...


@dataclass(frozen=True)
class Carried:
    """A payload besides the keyframes: sent at the rate drawn for ``slot`` (the last one
    ended when it was queued: the link's rate until the next slot ends)."""

    slot: int
    payload: bytes
    write: Callable[[bytes], None]
    what: str                   #: for the log, e.g. "relocalisation request (frame 212)"


def write_with_retry(write: Callable[[], None], retry_s: float,
                     clock: Callable[[], float] = time.monotonic,
                     sleep: Callable[[float], None] = time.sleep,
                     pause_s: float = 0.1) -> Exception | None:
    """Call ``write`` until it succeeds or ``retry_s`` has passed since the first try; None on
    success, else the last failure."""
    deadline = clock() + retry_s
    while True:
        try:
            write()
            return None
        except Exception as exc:           # rclpy's RCLError: the write timed out
            if clock() > deadline:
                return exc
            sleep(pause_s)


class UplinkSender:
    """Requests in, keyframes and throughput out, one slot at a time in request order."""

    def __init__(self, shaper: Shaper, encode: Callable[[int, int], Encoded | None],
                 write: Callable[[bytes], None], report: Callable[[SlotThroughput], None],
                 log_error: Callable[[str], None], default_rate: float,
                 retry_s: float = 30.0, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """``encode(slot, frame_id)`` gives a frame's bytes (None: no longer held);
        ``write(bytes)`` publishes one keyframe; ``report`` publishes a slot's throughput."""
        self.shaper, self.encode, self.write, self.report = shaper, encode, write, report
        self.log_error = log_error
        self.default_rate = default_rate
        self.retry_s, self.clock, self.sleep = retry_s, clock, sleep
        #: slot → (d_k Mbit/s, rate state) the device drew when the slot ended
        self.rates: dict[int, tuple[float, int]] = {}
        self._jobs: queue.Queue[tuple[int, list[int]] | Carried | None] = queue.Queue()
        self._thread: threading.Thread | None = None
        self._carried_bytes = 0     #: carried since the last slot report (the uplink thread's)

    def request(self, slot: int, frame_ids: list[int]) -> None:
        """The edge asked for ``frame_ids`` of ``slot``; sent in order behind earlier slots."""
        self._jobs.put((slot, list(frame_ids)))

    def carry(self, item: Carried) -> None:
        """Send ``item`` behind the requests queued before it."""
        self._jobs.put(item)

    def send_slot(self, slot: int, frame_ids: list[int]) -> SlotThroughput:
        """One request, synchronously: encode, send through the shaper, report (with the
        bytes carried since the last report)."""
        rate, state = self.rates.get(slot, (self.default_rate, 0))
        if rate <= 0:                   # an outage: the link carries nothing this slot
            if frame_ids:
                self.log_error(f"slot {slot}: the uplink is down (0 Mbit/s); "
                               f"{len(frame_ids)} requested keyframe(s) not sent")
            throughput = SlotThroughput(slot, 0.0, state, 0, 0.0, 0)
        else:
            encoded = [e for f in frame_ids if (e := self.encode(slot, f)) is not None]
            self.shaper.start_slot(slot, rate, state)
            for frame_id, payload, size in encoded:
                self.shaper.send(size, functools.partial(
                    self._write, self.write, payload, f"slot {slot}: keyframe {frame_id}"))
            throughput = self.shaper.end_slot()
        throughput = replace(throughput, request_bytes=self._carried_bytes)
        self._carried_bytes = 0
        self.report(throughput)
        return throughput

    def send_carried(self, item: Carried) -> bool:
        """One carried payload, synchronously, at its slot's rate; False (logged) when the
        uplink is down then or the write failed."""
        rate, _ = self.rates.get(item.slot, (self.default_rate, 0))
        if rate <= 0:
            self.log_error(f"slot {item.slot}: the uplink is down (0 Mbit/s); {item.what} "
                           "not sent")
            return False
        written: list[bool] = []
        self.shaper.carry(len(item.payload), lambda: written.append(
            self._write(item.write, item.payload, item.what)), rate)
        if written[0]:
            self._carried_bytes += len(item.payload)
        return written[0]

    def _write(self, write: Callable[[bytes], None], payload: bytes, what: str) -> bool:
        """``write(payload)``, retried for ``retry_s``; False, and ``what`` logged as given
        up, when it kept failing."""
        failure = write_with_retry(lambda: write(payload), self.retry_s, self.clock, self.sleep)
        if failure is not None:
            self.log_error(f"{what} not written within {self.retry_s:g} s ({failure}); "
                           "given up")
        return failure is None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="uplink", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            if isinstance(job, Carried):
                self.send_carried(job)
            else:
                self.send_slot(*job)

    def close(self, timeout: float = 5.0) -> None:
        """Stop after the slot being sent (queued requests are dropped with the process)."""
        self._jobs.put(None)
        if self._thread is not None:
            self._thread.join(timeout=timeout)
