"""Waiting for reliable readers to acknowledge, without stopping the whole process.

rclpy's ``Publisher.wait_for_all_acked`` keeps Python's GIL for as long as it waits (measured:
a thread ticking every 10 ms saw a 2.0 s gap during a 2 s wait on a reader that did not
acknowledge). A node that waits for acknowledgements on a worker thread — the device's upload
thread after a slot's keyframes — would freeze its tracking with it, for up to the lease
duration (20 s) of an edge that died. :func:`wait_for_acks` waits in short slices and sleeps in
between, so the other threads run.
"""

from __future__ import annotations

import time

from rclpy.duration import Duration
from rclpy.publisher import Publisher

SLICE_S = 0.01


def wait_for_acks(publisher: Publisher, timeout_s: float) -> bool:
    """Whether every reliable reader acknowledged what ``publisher`` wrote within
    ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        if publisher.wait_for_all_acked(Duration(nanoseconds=1_000_000)):   # 1 ms with the GIL
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(SLICE_S)
