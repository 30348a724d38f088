"""An rclpy node with its own context and executor, inside a process that does other work.

The launcher's monitor, ``twinslam nodes`` and the tests each watch a domain from a process
that is not a node's process: they need a context of their own (a process may hold several,
one per domain it watched), signal handling left to the host program, and spinning that is
bounded in time.

rclpy's ``SingleThreadedExecutor`` spins by default: each turn builds a wait set, in Python,
over every publisher, subscription and event handler of the node. A host that holds many
(``bench.edge_scaling``'s fifty emulated devices: 250 of them) can ask for the
``EventsExecutor`` the nodes spin on (``executor="events"``), which takes each sample as an
event instead: py-spy put 78 % of the fifty devices' thread in building wait sets. The
launcher's monitor spins on it too. A callback that takes the message's info must accept it
as rclpy 7.1.6's ``EventsExecutor`` hands it — one argument, the (message, info) pair, where
rclpy's Python executors pass two; a plain two-parameter function raises ``SystemError: null
argument to internal routine`` there (:func:`twinslam.live.monitor.with_info` takes both).
Moved onto it, the launcher's CPU over a 300-frame run went from 4.1–4.5 s to 3.7–3.8 s, and
over four devices' from 10.2–10.7 s to 8.1 s (2026-12-05, ``bench.process_cpu``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from twinslam.node_runtime.interrupts import Spinning


def events_executor(*, context: Context) -> Executor:
    """rclpy's ``EventsExecutor`` on ``context``, also in a process whose ``sys.stderr`` has
    no file descriptor (a notebook, an IDE's console, pytest's captured output): rclpy's
    factory first enables :mod:`faulthandler` on ``sys.stderr``, which raises
    ``io.UnsupportedOperation`` there — the process's own stderr is lent to it meanwhile."""
    try:
        sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):    # io.UnsupportedOperation among them
        stderr, sys.stderr = sys.stderr, sys.__stderr__
        try:
            return EventsExecutor(context=context)
        finally:
            sys.stderr = stderr
    return EventsExecutor(context=context)


#: the executors a session spins on, by name
EXECUTORS: dict[str, Callable[..., Executor]] = {"single": SingleThreadedExecutor,
                                                 "events": events_executor}


class RosSession:
    """``node`` on a fresh context (the environment's domain and DDS settings at creation),
    spun by the ``executor`` named (one of :data:`EXECUTORS`)."""

    def __init__(self, name: str, namespace: str | None = None,
                 args: list[str] | None = None, executor: str = "single") -> None:
        if executor not in EXECUTORS:
            raise ValueError(f"executor {executor!r}: choose from {', '.join(EXECUTORS)}")
        self.context = Context()
        rclpy.init(args=args or [name], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(name, namespace=namespace, context=self.context)
        self.executor = EXECUTORS[executor](context=self.context)
        self.executor.add_node(self.node)

    def spin_once(self, timeout_s: float = 0.0) -> None:
        with Spinning():           # a Ctrl-C meanwhile is raised as the spin returns
            self.executor.spin_once(timeout_sec=timeout_s)

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Run callbacks until ``predicate()`` holds or ``timeout_s`` passes; returns it."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self.context.ok():
                break
            self.spin_once(min(remaining, 0.1))
        return bool(predicate())

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> RosSession:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
