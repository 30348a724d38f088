"""``twinslam``: the command-line entry point for the offline tools and the live pipeline.

    twinslam sim --covis FILE --policy lff,pu,adapt,reference [--channel markov:N=2]
                 [--vmax 45] [--slots 200] [--seeds 5] [--csv OUT]   # mbrl:CHECKPOINT too
    twinslam train --covis FILE --channel markov:N=2 --vmax 45 [--rate-model regime] -o OUT.pt
    twinslam extract SEQUENCE -o covis.npz [--start N] [--end N] [--features 1000]
    twinslam record SEQUENCE -o BAG [--start N] [--end N]   # the player's topics as MCAP
    twinslam trace generate -o uplink.csv --outage 300:10   # or: trace info FILE
    twinslam nodes [--timeout 3.5]        # the ROS graph on $ROS_DOMAIN_ID (ros2 node list)
    twinslam launch --scenario revisit-lost --policy lff,adapt --loopback
    twinslam evaluate --policy lff,pu,adapt --seeds 3     # live: policy x scenario x seed
    twinslam experiment fig7 --policy UDT=results/amm_udt.pt   # paper figures
    twinslam demo                         # what `make run` runs
    twinslam parameters --write           # docs/parameters.md from the nodes' declarations
    twinslam precompile                   # the numba kernels, once after an install

`twinslam COMMAND --help` documents every option of a command.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import signal
import sys
import threading
from collections.abc import Iterator

from twinslam.cli.console import HelpFormatter
from twinslam.node_runtime.interrupts import interrupt

#: the commands (modules of twinslam.cli.commands) in the order ``twinslam --help`` lists them
COMMANDS = ("sim", "train", "extract", "record", "nodes", "hosts", "launch", "evaluate",
            "calibrate", "demo", "trace", "experiment", "parameters", "precompile")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line with every command, or with ``command`` alone: a command's module
    imports what it runs (rclpy, numba, torch, the simulator), and importing all fourteen took
    2.7 s of CPU on a slow 2-core VM before ``twinslam sim`` could start, its own 1.1 s
    (``bench.startup``)."""
    parser = argparse.ArgumentParser(prog="twinslam", description=__doc__,
                                     formatter_class=HelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub.add_parser = functools.partial(sub.add_parser,  # type: ignore[method-assign]
                                       formatter_class=HelpFormatter)
    for name in (command,) if command in COMMANDS else COMMANDS:
        importlib.import_module(f"twinslam.cli.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    named = argv[0] if argv and argv[0] in COMMANDS else None
    args = build_parser(named).parse_args(argv)
    with sigterm_as_interrupt():
        return int(args.func(args))


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (``kill``, a job scheduler, a container stopping) ends a command as Ctrl-C
    does: a live run stops the nodes it started instead of leaving them running (measured:
    a killed ``twinslam launch`` left its player, devices and edge behind). Both arrive as
    KeyboardInterrupt, held back while the main thread is inside rclpy's executor
    (:mod:`twinslam.node_runtime.interrupts`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


if __name__ == "__main__":
    sys.exit(main())
