"""The experiments' sweeps on an executor (:mod:`twinslam.common.executor`: this process,
local worker processes or Ray), each result reported as it lands."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from twinslam.common.executor import (
    Executor,
    LocalExecutor,
    TaskFailure,
    make_executor,
    run_tasks,
)

T = TypeVar("T")
R = TypeVar("R")


def one_torch_thread() -> None:
    """A local worker's torch: one thread (the workers share the cores). Imported here, not
    at the top: a command that runs no torch (``twinslam sim``) must not load it."""
    import torch

    torch.set_num_threads(1)


def executor_for(name: str = "local", jobs: int | None = None,
                 address: str | None = None) -> Executor:
    """The executor of a command's ``--executor``/``--jobs``/``--ray-address``."""
    return make_executor(name, jobs, address, initializer=one_torch_thread)


def run_all(fn: Callable[[T], R], tasks: Sequence[T], executor: Executor | None,
            describe: Callable[[T], str], label: Callable[[R], str],
            progress: Callable[[str], None] | None,
            failures_file: Path | None = None,
            failures: list[TaskFailure] | None = None) -> list[R]:
    """``fn`` (a module-level function) over ``tasks`` on ``executor`` (None: in this
    process), reporting "[i/n] label (elapsed, ETA)" after each; the results of the tasks
    that finished, in task order. A failed task is reported with ``describe(task)`` and its
    traceback (also in ``failures_file``) and added to ``failures``; the others finish."""
    sweep = run_tasks(fn, tasks, executor or LocalExecutor(1), describe, label, progress,
                      failures_file)
    if failures is not None:
        failures += sweep.failures
    return sweep.in_order()
