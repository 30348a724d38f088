"""Stamps and headers: seconds ↔ ``builtin_interfaces/Time`` (and ``Duration``), and filling
``std_msgs/Header``.

Every node stamps with its own clock (``node.get_clock()``, so ``use_sim_time`` works); these
helpers only convert. One place for it, so the device, the edge and the player agree on the
nanosecond rounding that pairs a colour image with its depth image.
"""

from __future__ import annotations

import math
from typing import Protocol, TypeVar

from builtin_interfaces.msg import Duration, Time
from std_msgs.msg import Header


def _sec_nanosec(seconds: float) -> tuple[int, int]:
    """Whole seconds and nanoseconds of ``seconds`` (nanoseconds rounded, never 10⁹)."""
    sec = math.floor(seconds)
    return sec, min(round((seconds - sec) * 1e9), 999_999_999)


def ros_time(stamp: float) -> Time:
    """``builtin_interfaces/Time`` of a time in seconds (nanoseconds rounded, never 10⁹)."""
    sec, nanosec = _sec_nanosec(stamp)
    return Time(sec=sec, nanosec=nanosec)


def ros_duration(seconds: float) -> Duration:
    """``builtin_interfaces/Duration`` of a span in seconds, rounded as :func:`ros_time`."""
    sec, nanosec = _sec_nanosec(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def time_seconds(time: Time | Duration) -> float:
    """A ``builtin_interfaces/Time`` (or ``Duration``) in seconds."""
    return int(time.sec) + int(time.nanosec) * 1e-9


def time_key(time: Time) -> int:
    """A ``builtin_interfaces/Time`` in integer nanoseconds: the key that pairs a colour and
    a depth image of one frame, and a frame's summary with its pose."""
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def stamp_seconds(header: Header) -> float:
    """A header's stamp in seconds."""
    return time_seconds(header.stamp)


def stamp_key(header: Header) -> int:
    """A header's stamp in integer nanoseconds (:func:`time_key`)."""
    return time_key(header.stamp)


class Stamped(Protocol):
    """A message with a ``std_msgs/Header``."""

    header: Header


S = TypeVar("S", bound=Stamped)


def set_header(msg: S, stamp: float, frame_id: str) -> S:
    """Fill ``msg.header`` with a stamp in seconds and a frame id; returns ``msg``."""
    msg.header.stamp = ros_time(stamp)
    msg.header.frame_id = frame_id
    return msg
