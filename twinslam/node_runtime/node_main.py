"""The life of a one-node process: ``rclpy.init``, build the node, spin, tear down.

Every twinslam executable is such a process (``ros2 run twinslam edge_mapper``). A node that
cannot start — a refused parameter, a missing dataset or checkpoint — logs why and exits with 2,
the exit code of a usage error, instead of a traceback. SIGINT and SIGTERM end the spin; the
node's ``close`` (if it has one) runs before the node is destroyed, so worker threads stop and
the last samples are acknowledged.

The nodes spin on rclpy's C++ ``EventsExecutor`` (``rclpy.experimental``, in Jazzy's rclpy
7.1): it takes each sample as an event instead of rebuilding a wait set in Python every turn.
On ``bench.dds``'s camera path it cut the median latency from 5.1 to 3.8 ms (BENCHMARKS.md;
measured on a loaded machine). ``TWINSLAM_EXECUTOR=single`` runs a node on rclpy's
``SingleThreadedExecutor`` instead, should the experimental executor misbehave somewhere.
Freed memory stays in the process (:mod:`twinslam.node_runtime.allocator`): a frame's buffers
are reused instead of page-faulted in anew; the math libraries' thread pools are one thread
each unless the user sized them (:mod:`twinslam.node_runtime.math_threads`).

Signals only ever *ask* for the stop; the main loop acts on it between two executor turns.
rclpy's own handlers are not installed (``SignalHandlerOptions.NO``): they shut the context
down from rclpy's signal thread, and Python's default handler raises ``KeyboardInterrupt`` in
whatever Python code runs — both can land while the EventsExecutor registers the node's
entities (its first turn calls back into Python for every subscription and waitable). A
registration cut in half leaves callbacks the executor no longer tracks, and its destructor
then aborts the process ("Destroying callback manager with callbacks remaining", exit -6):
26 of 88 edge nodes signalled the moment they logged "listening on" did so, 0 of 80 since.
While the EventsExecutor exists it takes SIGINT/SIGTERM with its own signal set and shuts
the context down after a turn; destroyed, that signal set leaves the default disposition
behind, so the stop handler is installed again for the rest of the teardown.

A node's process ends once the node is torn down (:func:`exit_process`): the ``atexit``
handlers run and the standard streams are flushed, but the interpreter does not tear its modules
down one by one — 0.8 s of a twin node's exit (torch), 0.3 s of the others', measured on an idle
machine; on a loaded one a twin node stopped with SIGTERM took longer than the 5 s ``ros2
launch`` (and the tests) grant before SIGKILL. A node forked from a fork server
(:mod:`twinslam.hosts.forked`) always ended this way. What a node's worker threads still had to
write is written by its ``close`` before.

The node's destruction — the DDS participant's deletion with it — is bounded
(:mod:`twinslam.node_runtime.middleware_teardown`): Fast DDS as the PyPI wheels build it can
deadlock there against a discovery callback (a peer leaving at the same moment), and a node
stuck so prints where and exits with code 1 after 5 s instead of waiting to be killed.

A node started by a test, a benchmark or ``twinslam launch`` through
:class:`~twinslam.hosts.loopback.ProcessDomain` ends with the process that started it, even
one killed outright (:mod:`twinslam.parent_watch`).

``kill -USR1 PID`` prints every thread's Python stack to the node's stderr and the node goes
on (:data:`STACKS_SIGNAL`): where a node that stopped answering, or does not end when asked,
is stuck.
"""

from __future__ import annotations

import atexit
import faulthandler
import gc
import os
import signal
import sys
from collections.abc import Callable
from typing import NoReturn, Protocol, TypeVar, runtime_checkable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from twinslam.node_runtime.allocator import keep_freed_memory
from twinslam.node_runtime.long_lived_objects import keep_survivors_out
from twinslam.node_runtime.math_threads import one_math_thread
from twinslam.node_runtime.middleware_teardown import teardown_bound
from twinslam.parent_watch import PARENT_ENV, stop_with_parent

N = TypeVar("N", bound=Node)

#: the signal that prints a node's stacks (:func:`faulthandler.register`: from the signal
#: handler itself, so a thread stuck in C code holding the interpreter is shown too)
STACKS_SIGNAL = signal.SIGUSR1


@runtime_checkable
class Closable(Protocol):
    """A node with work of its own to finish before it is destroyed (a background thread, a
    file to flush): its ``close`` runs after the executor stops, before ``destroy_node``."""

    def close(self) -> None: ...



def _init_hint() -> str:
    """What to check when ``rclpy.init`` failed, for the settings that commonly make it fail."""
    if os.environ.get("ROS_SECURITY_ENABLE", "").lower() == "true":
        return ("; ROS 2 security (SROS2) is asked for: ROS_SECURITY_KEYSTORE must hold this "
                "node's enclave, and the middleware must have DDS Security — the Fast DDS of "
                "the ROS 2 wheels on PyPI is built without it (docs/running.md, \"Security\")")
    return "; check ROS_DOMAIN_ID (0..232) and the --ros-args given"


EXECUTORS: dict[str, Callable[[], Executor]] = {"events": EventsExecutor,
                                                "single": SingleThreadedExecutor}


def executor_name() -> str:
    """The executor ``TWINSLAM_EXECUTOR`` names (``events`` when unset); ValueError when it
    names none."""
    name = os.environ.get("TWINSLAM_EXECUTOR", "") or "events"
    if name not in EXECUTORS:
        raise ValueError(f"TWINSLAM_EXECUTOR={name!r}: choose from {', '.join(EXECUTORS)}")
    return name


class StopRequest:
    """SIGINT/SIGTERM recorded as a request to stop, read by the spin loop between turns."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signal: int | None = None

    def __call__(self, signum: int, _frame: object) -> None:
        self.signal = signum

    @property
    def requested(self) -> bool:
        return self.signal is not None

    def install(self) -> None:
        """Make this the process's handler of SIGINT and SIGTERM (again)."""
        for sig in self.SIGNALS:
            signal.signal(sig, self)


class NodeStartError(Exception):
    """Raised by a node's constructor when it cannot start; the message says why."""


def run_node(name: str, factory: Callable[[], N], args: list[str] | None = None,
             until: Callable[[N], bool] | None = None,
             started: Callable[[N], None] | None = None, long_lived: bool = False) -> int:
    """Init, ``factory()``, spin until shutdown (or ``until(node)``), tear down; returns the
    process exit code (0, or 2 when node ``name`` could not start). A node whose state is
    many ``long_lived`` Python objects (the edge's maps) keeps them out of the collector's
    full collections once they survived one (:mod:`.long_lived_objects`)."""
    try:
        make_executor = EXECUTORS[executor_name()]
    except ValueError as exc:
        rclpy.logging.get_logger(name).fatal(str(exc))
        return 2
    faulthandler.register(STACKS_SIGNAL, file=sys.stderr, all_threads=True)
    keep_freed_memory()
    one_math_thread()
    if long_lived:
        keep_survivors_out()
    stop = StopRequest()
    stop.install()
    if stop_with_parent():
        rclpy.logging.get_logger(name).warning(
            f"the process that started this node ({PARENT_ENV}) is gone: not starting")
        return 0
    try:
        rclpy.init(args=sys.argv if args is None else args,
                   signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:          # rclpy's RCLError: arguments, domain, security enclave
        rclpy.logging.get_logger(name).fatal(f"cannot start ROS 2: {exc}{_init_hint()}")
        return 2
    node: N | None = None
    executor: Executor | None = None
    try:
        try:
            node = factory()
        except NodeStartError as exc:
            rclpy.logging.get_logger(name).fatal(str(exc))
            return 2
        if stop.requested:            # SIGINT/SIGTERM while it was starting: not a failure
            return 0
        if started is not None:
            started(node)
        if long_lived:
            gc.collect()              # what start-up made, frozen before the first callback
        executor = make_executor()
        executor.add_node(node)
        while not stop.requested and rclpy.ok() and (until is None or not until(node)):
            try:
                executor.spin_once(timeout_sec=0.1)
            except Exception:
                if rclpy.ok():
                    raise
                break                 # the context was shut down mid-spin: a clean stop
        return 0
    except ExternalShutdownException:
        return 0
    finally:
        if executor is not None:
            executor.shutdown()       # before the node goes: no callback runs on a dead node
            executor = None           # its signal set goes with it ...
            stop.install()            # ... leaving the default disposition: ours again
        if node is not None:
            finishing: object = node      # a node class may add close(): Node has none
            if isinstance(finishing, Closable):
                finishing.close()
        with teardown_bound():            # the DDS participant's deletion can deadlock
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        # the node is gone and the process is ending: a signal now has nothing left to stop.
        # Ignored, not left to Python's exit, which puts the default action back (the process
        # would die of a SIGTERM that lands while the interpreter and DDS wind down)
        for sig in StopRequest.SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def exit_process(code: int) -> NoReturn:
    """End a node's process with ``code`` once :func:`run_node` returned it: the ``atexit``
    handlers run and the standard streams are flushed, the interpreter's teardown of its
    modules skipped (the module docstring says why). The node's ``close`` has finished its
    workers' writes by then."""
    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code & 0xFF)
