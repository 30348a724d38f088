"""Ctrl-C and SIGTERM in the launcher and the other programs that spin a monitor: raised as
KeyboardInterrupt, but never inside rclpy's executor, where pybind11 turns it into "Unable to
convert call argument" and the command exits 1 instead of 130 (seen on SIGTERM)."""

from __future__ import annotations

import signal

import pytest

from twinslam.node_runtime.interrupts import Spinning, interrupt


def test_an_interrupt_outside_a_spin_is_raised_at_once() -> None:
    with pytest.raises(KeyboardInterrupt):
        interrupt(signal.SIGTERM, None)


def test_an_interrupt_during_a_spin_is_raised_as_the_spin_returns() -> None:
    reached_the_end = False
    with pytest.raises(KeyboardInterrupt):
        with Spinning():
            interrupt(signal.SIGINT, None)         # the handler returns: rclpy goes on
            with Spinning():                       # a nested spin does not raise it yet
                pass
            reached_the_end = True
    assert reached_the_end
    assert Spinning.depth == 0 and not Spinning.interrupted
    with Spinning():                               # handled once: the next spin is quiet
        pass
