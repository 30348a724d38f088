"""The spin loop: waits on Cyclone, then runs callbacks on the calling (spin) thread.

Cyclone's listener threads only signal a WaitSet; decoding and user callbacks happen here, so
a node's state needs no locks against its own callbacks, as with rclpy's single-threaded
executor. Timers are scheduled on the monotonic clock without drift (``next_due += period``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

from cyclonedds.core import WaitSet

from node_runtime.context import DomainJoinError, get_context, init, shutdown
from node_runtime.node import Node

_MAX_WAIT_S = 0.1  # upper bound of one wait, so new endpoints and shutdown are seen promptly


class SingleThreadedExecutor:
    """Runs the callbacks of one or more nodes of the current context on one thread."""

    def __init__(self) -> None:
        self.context = get_context()
        self.nodes: list[Node] = []
        self._waitset = WaitSet(self.context.participant)
        self._waitset.attach(self.context.guard)
        self._attached: set[int] = set()

    def add_node(self, node: Node) -> None:
        if node not in self.nodes:
            self.nodes.append(node)

    def _sync_conditions(self) -> None:
        for node in self.nodes:
            for sub in node.subscriptions:
                if id(sub.condition) not in self._attached:
                    self._waitset.attach(sub.condition)
                    self._attached.add(id(sub.condition))

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to ``timeout_sec`` for work, then do all that is ready."""
        self._sync_conditions()
        now = time.monotonic()
        due = [t.next_due for n in self.nodes for t in n.timers if not t.cancelled]
        wait = _MAX_WAIT_S if timeout_sec is None else min(timeout_sec, _MAX_WAIT_S)
        if due:
            wait = min(wait, max(0.0, min(due) - now))
        if wait > 0:
            self._waitset.wait(int(wait * 1e9))
        self.context.guard.take()
        for node in list(self.nodes):
            for sub in list(node.subscriptions):
                if not self.context.ok():
                    return
                sub.take_and_dispatch()
            now = time.monotonic()
            for timer in list(node.timers):
                if timer.cancelled or now < timer.next_due:
                    continue
                timer.next_due += timer.period
                if timer.next_due < now:  # fell behind by more than a period: do not burst
                    timer.next_due = now + timer.period
                timer.callback()

    def spin(self) -> None:
        """Run until ``shutdown()``, SIGINT or SIGTERM."""
        while self.context.ok():
            self.spin_once()

    def spin_until(self, predicate: Callable[[], bool], timeout_sec: float) -> bool:
        """Spin until ``predicate()`` holds or ``timeout_sec`` passes; returns the predicate."""
        deadline = time.monotonic() + timeout_sec
        while self.context.ok() and not predicate():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            self.spin_once(remaining)
        return bool(predicate())


def spin(node: Node) -> None:
    """Run ``node``'s callbacks until shutdown (like ``rclpy.spin``)."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.spin()


def start_node(name: str, parameters: dict[str, Any], args: list[str] | None = None) -> Node:
    """``init()`` and a node named ``name`` with ``parameters`` declared (defaults, then the
    command line's and parameter files' values): every entry point's first step."""
    try:
        init(args=args)
    except (DomainJoinError, ValueError) as exc:     # ValueError: a bad ROS_DOMAIN_ID
        print(f"[FATAL] [{name}]: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    node = Node(name)
    for key, default in parameters.items():
        node.declare_parameter(key, default)
    return node


def fail(node: Node, message: str) -> int:
    """A node that cannot start (bad parameter, missing input): log why, leave the domain,
    and return the exit code 2 of a usage error."""
    node.get_logger().error(message)
    node.destroy_node()
    shutdown()
    return 2


def run(node: Node, until: Callable[[], bool] | None = None,
        on_exit: Callable[[], None] | None = None) -> None:
    """Spin ``node`` until SIGINT/SIGTERM/``shutdown()`` (or ``until()`` holds), run
    ``on_exit``, then destroy it and shut down.

    The whole life of a one-node process after ``init()``: the teardown runs even when a
    callback raises, so the participant always leaves the domain cleanly.
    """
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        if until is None:
            executor.spin()
        else:
            executor.spin_until(until, float("inf"))
    finally:
        if on_exit is not None:
            on_exit()
        node.destroy_node()
        shutdown()


def spin_once(node: Node, timeout_sec: float | None = None) -> None:
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.spin_once(timeout_sec)
