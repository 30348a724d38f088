"""Ctrl-C and SIGTERM in a program that watches a domain from its main thread (the launcher's
monitor, ``twinslam nodes``): a KeyboardInterrupt, but never from inside rclpy's executor.

Python runs a signal handler in the main thread between two bytecodes. While that thread is in
an executor's ``spin_once``, the next bytecodes may be those of rclpy turning a message into the
argument of a callback; an exception raised there comes out of pybind11 as "Unable to convert
call argument '0' to Python object" (seen: ``twinslam launch`` exited 1 instead of 130 on
SIGTERM). :func:`interrupt` notes the signal there instead, and the session raises
KeyboardInterrupt as the spin returns (:meth:`twinslam.node_runtime.session.RosSession.spin_once`).
No rclpy here: the command line installs the handler before it knows whether it will spin.
"""

from __future__ import annotations

import threading


class Spinning:
    """Counts the main thread's spins in progress; marks an interrupt that came during one."""

    depth = 0
    interrupted = False

    def __enter__(self) -> Spinning:
        if threading.current_thread() is threading.main_thread():
            Spinning.depth += 1
        return self

    def __exit__(self, *_exc: object) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        Spinning.depth -= 1
        if Spinning.interrupted and not Spinning.depth:
            Spinning.interrupted = False
            raise KeyboardInterrupt


def interrupt(_signum: int, _frame: object) -> None:
    """SIGINT or SIGTERM: KeyboardInterrupt at once, or as the main thread's spin returns."""
    if Spinning.depth:
        Spinning.interrupted = True
        return
    raise KeyboardInterrupt
