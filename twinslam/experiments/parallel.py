"""The experiments' sweeps on an executor (:mod:`twinslam.sweeps`: this process,
local worker processes or Ray), each result reported as it lands. A local worker's torch runs
one thread (the executor's worker set-up sees to it, whether torch is loaded yet or not)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from twinslam.sweeps import Executor, LocalExecutor, TaskFailure, run_tasks

T = TypeVar("T")
R = TypeVar("R")


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
