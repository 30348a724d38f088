"""Independent experiment runs over worker processes, each result reported as it lands."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import TypeVar

import torch

T = TypeVar("T")
R = TypeVar("R")


def _init_worker() -> None:
    torch.set_num_threads(1)       # jobs share the cores; one thread each uses them best


def run_all(fn: Callable[[T], R], tasks: list[T], jobs: int, label: Callable[[R], str],
            progress: Callable[[str], None] | None) -> list[R]:
    """``fn`` over ``tasks`` in order, in ``jobs`` spawned worker processes when > 1 (``fn``
    must then be a module-level function), reporting "i/n label" after each result."""
    results: list[R] = []

    def report(res: R) -> None:
        results.append(res)
        if progress:
            progress(f"{len(results)}/{len(tasks)} {label(res)}")

    if jobs <= 1:
        for task in tasks:
            report(fn(task))
        return results
    with ProcessPoolExecutor(jobs, mp_context=get_context("spawn"),
                             initializer=_init_worker) as pool:
        for res in pool.map(fn, tasks):
            report(res)
    return results
