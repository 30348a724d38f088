"""An rclpy node with its own context and executor, inside a process that does other work.

The launcher's monitor, ``twinslam nodes`` and the tests each watch a domain from a process
that is not a node's process: they need a context of their own (a process may hold several,
one per domain it watched), signal handling left to the host program, and spinning that is
bounded in time.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from twinslam.node_runtime.interrupts import Spinning


class RosSession:
    """``node`` on a fresh context (the environment's domain and DDS settings at creation)."""

    def __init__(self, name: str, namespace: str | None = None,
                 args: list[str] | None = None) -> None:
        self.context = Context()
        rclpy.init(args=args or [name], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(name, namespace=namespace, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
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
