"""Where a sweep's independent tasks run: this process, a pool of local worker processes, or a
Ray cluster (``ray.init()`` on this machine, or one joined by address).

Every sweep of the project — training runs, evaluation seeds, figure points, live runs — is a
list of tasks that share nothing, each a module-level function of one picklable argument. An
:class:`Executor` runs them and hands back ``(index, outcome)`` pairs in the order they finish;
:func:`run_tasks` turns those into results in task order, a progress line with an ETA per task
that lands, and a :class:`TaskFailure` (its traceback kept) for a task that raised — the other
tasks go on. A task's result depends only on its argument (seeds are in the task), so the same
sweep gives the same numbers whichever executor ran it.

Ray is imported only when ``ray`` is the executor: the local runs need no Ray installed.
"""

from __future__ import annotations

import os
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from functools import partial
from multiprocessing import get_context
from pathlib import Path
from types import TracebackType
from typing import Any, Generic, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: the executors ``--executor`` offers
EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class TaskFailure:
    """A task that raised: which one (its index and what it was) and the traceback."""

    index: int
    task: str
    error: str

    @property
    def last_line(self) -> str:
        lines = self.error.strip().splitlines()
        return lines[-1] if lines else "?"


@dataclass(frozen=True)
class Outcome(Generic[R]):
    """What a worker sends back: the result, or the formatted traceback of what it raised (an
    exception object may not pickle; its text always does)."""

    value: R | None
    error: str = ""


def _call(fn: Callable[[T], R], task: T) -> Outcome[R]:
    try:
        return Outcome(fn(task))
    except Exception:            # reported with its task; the sweep goes on
        return Outcome(None, traceback.format_exc())


def _outcome_of(get: Callable[[], Outcome[R]]) -> Outcome[R]:
    """A worker's outcome, or — when the worker itself died (a crash, a killed process: the
    pool or Ray raises instead of handing one back) — that error as the task's failure."""
    try:
        return get()
    except Exception:
        return Outcome(None, traceback.format_exc())


def _one_thread_per_worker() -> None:
    """Workers share the cores: one BLAS/OpenMP thread each uses them best. torch reads
    OMP_NUM_THREADS when a task first imports it; a torch the worker already loaded (a spawned
    worker re-imports the main module, and a script's imports may load it) is set directly —
    else each of N workers runs as many threads as the machine has cores."""
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["MKL_NUM_THREADS"] = "1"
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def _init_worker(initializer: Callable[[], None] | None) -> None:
    _one_thread_per_worker()
    if initializer is not None:
        initializer()


class Executor:
    """Runs ``fn`` over tasks; a context manager that releases its workers on exit."""

    name = ""

    def submit_all(self, fn: Callable[[T], R], tasks: Sequence[T]
                   ) -> Iterator[tuple[int, Outcome[R]]]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (and a Ray this executor started)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


class LocalExecutor(Executor):
    """``jobs`` spawned worker processes on this machine; 1: in this process, in order."""

    name = "local"

    def __init__(self, jobs: int = 1, initializer: Callable[[], None] | None = None) -> None:
        if jobs < 1:
            raise ValueError(f"--jobs must be >= 1, got {jobs}")
        self.jobs = jobs
        self._initializer = initializer
        self._pool: ProcessPoolExecutor | None = None

    def submit_all(self, fn: Callable[[T], R], tasks: Sequence[T]
                   ) -> Iterator[tuple[int, Outcome[R]]]:
        if self.jobs <= 1:
            for i, task in enumerate(tasks):
                yield i, _call(fn, task)
            return
        self._pool = ProcessPoolExecutor(self.jobs, mp_context=get_context("spawn"),
                                         initializer=_init_worker,
                                         initargs=(self._initializer,))
        futures: dict[Future[Outcome[R]], int] = {
            self._pool.submit(_call, fn, task): i for i, task in enumerate(tasks)}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield futures[future], _outcome_of(future.result)
        self.close()                   # a sweep's workers go with it (fig8 runs one per N)

    def close(self) -> None:
        if self._pool is not None:       # an interrupt must not wait for every queued task
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RayExecutor(Executor):
    """Each task a Ray task of one CPU. ``address``: join that cluster (``ray start --head``
    printed it; "auto" finds one on this machine); none: start a local Ray here with ``cpus``
    CPUs (all when None), shut down again on close. The workers import this package, so every
    node of a cluster needs it installed, nothing else."""

    name = "ray"

    def __init__(self, address: str | None = None, cpus: int | None = None) -> None:
        try:
            import ray
        except ImportError as exc:            # pinned in requirements.txt; say what to do
            raise RuntimeError("--executor ray needs Ray: pip install -r requirements.txt "
                               "(or pip install ray)") from exc
        self._ray: Any = ray
        if address:
            _check_reachable(address)
        self._started = not ray.is_initialized()
        self._pending: list[Any] = []
        if self._started:
            import logging
            try:
                ray.init(address=address, num_cpus=None if address else cpus,
                         include_dashboard=False, log_to_driver=False,
                         logging_level=logging.WARNING,
                         runtime_env={"env_vars": {"OMP_NUM_THREADS": "1",
                                                   "MKL_NUM_THREADS": "1"}})
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise RuntimeError(f"could not start or join Ray"
                                   f"{f' at {address}' if address else ''}: {exc}") from exc

    def submit_all(self, fn: Callable[[T], R], tasks: Sequence[T]
                   ) -> Iterator[tuple[int, Outcome[R]]]:
        ray = self._ray
        remote = ray.remote(num_cpus=1, max_retries=0)(_call)
        refs = {remote.remote(fn, task): i for i, task in enumerate(tasks)}
        self._pending = list(refs)
        while self._pending:
            ready, self._pending = ray.wait(self._pending, num_returns=1)
            ref = ready[0]
            yield refs[ref], _outcome_of(partial(ray.get, ref))

    def close(self) -> None:
        for ref in self._pending:           # interrupted: nothing left running on the cluster
            self._ray.cancel(ref, force=True)
        self._pending = []
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A ``host:port`` (or ``ray://host:port``) that nothing answers is an error now: Ray
    itself retries a dead address for minutes."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return                                   # "auto" and the like: Ray resolves them
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise RuntimeError(f"could not start or join Ray at {address}: nothing answers there "
                           f"({exc.strerror or exc}); is `ray start --head` running?") from None


def make_executor(name: str, jobs: int | None = None, address: str | None = None,
                  initializer: Callable[[], None] | None = None) -> Executor:
    """The executor a command's ``--executor``, ``--jobs`` and ``--ray-address`` ask for
    (``jobs``: worker processes for ``local``, default 1; the CPUs of a Ray started here,
    default all)."""
    if name == "local":
        if address:
            raise ValueError("--ray-address needs --executor ray")
        return LocalExecutor(1 if jobs is None else jobs, initializer)
    if name == "ray":
        if jobs is not None and jobs < 1:
            raise ValueError(f"--jobs must be >= 1, got {jobs}")
        return RayExecutor(address, jobs)
    raise ValueError(f"unknown executor {name!r}: one of {', '.join(EXECUTORS)}")


def eta_text(done: int, total: int, started: float) -> str:
    """"12 s elapsed, ETA 1:05" from the tasks done so far (mean time a task)."""
    elapsed = time.monotonic() - started
    left = elapsed / done * (total - done) if done else float("nan")
    eta = (f"{int(left // 60)}:{int(left % 60):02d}" if left == left else "?")
    return f"{elapsed:.0f} s elapsed, ETA {eta}"


@dataclass
class Sweep(Generic[R]):
    """The results of the tasks that finished, by task index, and the failures."""

    results: dict[int, R]
    failures: list[TaskFailure]

    def in_order(self) -> list[R]:
        return [self.results[i] for i in sorted(self.results)]


def run_tasks(fn: Callable[[T], R], tasks: Sequence[T], executor: Executor,
              describe: Callable[[T], str], label: Callable[[R], str],
              progress: Callable[[str], None] | None = None,
              failures_file: Path | None = None,
              on_result: Callable[[int, R], None] | None = None) -> Sweep[R]:
    """Every task on ``executor``; after each, "[i/n] label (elapsed, ETA)" to ``progress``
    and ``on_result(index, result)`` (e.g. to append its rows); a failed task reported with
    ``describe(task)`` and its last line, its traceback appended to ``failures_file`` (or
    given whole to ``progress`` when there is none)."""
    started = time.monotonic()
    sweep: Sweep[R] = Sweep({}, [])
    if failures_file is not None:
        failures_file.unlink(missing_ok=True)
    for count, (index, outcome) in enumerate(executor.submit_all(fn, tasks), start=1):
        if outcome.error:
            failure = TaskFailure(index, describe(tasks[index]), outcome.error)
            sweep.failures.append(failure)
            where = ""
            if failures_file is not None:
                failures_file.parent.mkdir(parents=True, exist_ok=True)
                with failures_file.open("a", encoding="utf-8") as fh:
                    fh.write(f"== {failure.task}\n{failure.error}\n")
                where = f" (traceback in {failures_file})"
            if progress:
                progress(f"[{count}/{len(tasks)}] FAILED {failure.task}: {failure.last_line}"
                         f"{where}; the other tasks go on"
                         + ("" if failures_file else "\n" + failure.error.rstrip()))
            continue
        result: R = outcome.value  # type: ignore[assignment]
        sweep.results[index] = result
        if on_result:
            on_result(index, result)
        if progress:
            progress(f"[{count}/{len(tasks)}] {label(result)} "
                     f"({eta_text(count, len(tasks), started)})")
    return sweep
