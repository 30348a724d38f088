"""``twinslam precompile``: compile the numba kernels of the device, the edge and the synthetic
room once, after an install — ``make`` runs it; on a ROS 2 host, run it once after
``colcon build`` (``ros2 run twinslam twinslam precompile``), or the first start of each node
compiles its own kernels (measured: 58 s before the edge listened on 2 cores)."""

from __future__ import annotations

import argparse

from twinslam.cli.console import Subparsers


def run(_args: argparse.Namespace) -> int:
    from twinslam.cli.precompile import main  # loads numba and the cores: only when asked

    return main()


def register(sub: Subparsers) -> None:
    command = sub.add_parser(
        "precompile", help="compile the numba kernels once after installing (make does it; "
        "on a ROS 2 host run it after colcon build)",
        description=__doc__)
    command.set_defaults(func=run)
