"""Another commit's code beside this tree's, for before/after benchmarks in one run
("compare side by side in one run"): a temporary git worktree of the commit, and a driver
script run in a tree with only that tree's packages on the path (this venv's interpreter)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any, TypeVar

from bench.paths import REPO

T = TypeVar("T")


#: prepended to every driver: the tree's own twinslam must be the one imported
_CHECK_TREE = """
import sys
import twinslam
assert twinslam.__file__.startswith(sys.argv[-1]), twinslam.__file__
"""


@contextmanager
def baseline_tree(commit: str) -> Iterator[Path]:
    """A detached worktree of ``commit``, removed on exit (a bad commit fails here, before
    anything is measured)."""
    with tempfile.TemporaryDirectory(prefix="twinslam-bench-baseline-") as tmp:
        base = Path(tmp) / "baseline"
        done = subprocess.run(["git", "worktree", "add", "--detach", str(base), commit],
                              cwd=REPO, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"--baseline {commit}: git worktree add failed: "
                             f"{done.stderr.strip()}")
        try:
            yield base
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=REPO,
                           check=False, capture_output=True)


def absolute_paths(arg: str) -> str:
    """``arg`` with each comma-separated part that names a file or folder here (alone, or
    before a ``:N`` suffix: ``../shared/data/7scenes-1000:600``) made absolute: a baseline's
    tree runs in another working directory, where a relative path names nothing."""
    parts = []
    for part in arg.split(","):
        path, colon, suffix = part.rpartition(":")
        if part and Path(part).exists():
            part = str(Path(part).resolve())
        elif colon and path and Path(path).exists():
            part = f"{Path(path).resolve()}:{suffix}"
        parts.append(part)
    return ",".join(parts)


def run_in_tree(root: Path, driver: str, *args: str) -> Any:
    """Run ``driver`` (Python source whose last stdout line is JSON) with ``root`` as the
    working directory and the only project path, each argument's paths made absolute
    (:func:`absolute_paths`); returns that JSON. The driver may use only what both trees
    have."""
    args = tuple(absolute_paths(arg) for arg in args)
    done = subprocess.run([sys.executable, "-c", _CHECK_TREE + driver, *args, str(root)],
                          cwd=root, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(root)})
    if done.returncode:
        raise SystemExit(f"the benchmark failed in {root}:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def warm_kernels(root: Path) -> None:
    """The numba kernels of the tree at ``root`` compiled, or loaded from its cache, before
    anything is timed (``twinslam.cli.precompile``): they are cached beside their sources, so
    a fresh worktree compiles them on first use — up to a minute on 2 cores, inside the
    first round's first steps (a place walk's first slots took over a second each). A commit
    that predates the command is measured as it is, with a note."""
    done = subprocess.run([sys.executable, "-m", "twinslam.cli.precompile"], cwd=root,
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(root)})
    if done.returncode:
        print(f"the kernels of {root} could not be compiled ahead (its first round compiles "
              f"them): {done.stderr.strip().splitlines()[-1:] or done.returncode}", flush=True)


def alternately(baseline: str | None, rounds: int,
                measure: Callable[[int, str, Path], T]) -> dict[str, list[T]]:
    """``measure(round, label, root)`` on the baseline commit's tree ("baseline") and this one
    ("current"), the two alternating round by round so both see the same machine load;
    ``rounds`` results of each, by label. Without a baseline: this tree alone."""
    runs: dict[str, list[T]] = {"current": []} if baseline is None else {"baseline": [],
                                                                         "current": []}
    with baseline_tree(baseline) if baseline else nullcontext(REPO) as base:
        for label in runs:
            warm_kernels(base if label == "baseline" else REPO)
        for r in range(rounds):
            for label, results in runs.items():
                results.append(measure(r, label, base if label == "baseline" else REPO))
    return runs


def drive_alternately(baseline: str | None, rounds: int, driver: str, args: list[str],
                      describe: Callable[[Any], str]) -> dict[str, list[Any]]:
    """``driver`` (:func:`run_in_tree`) in the baseline's tree and this one, alternating
    round by round, each round's JSON printed as ``describe`` says; the results by tree as
    a reader names them (the baseline's commit, "this tree"), baseline first."""
    def measure(r: int, label: str, root: Path) -> Any:
        result = run_in_tree(root, driver, *args)
        print(f"round {r + 1} {label}: {describe(result)}", flush=True)
        return result

    trees = alternately(baseline, rounds, measure)
    return {(baseline if label == "baseline" and baseline else "this tree"): runs
            for label, runs in trees.items()}


def add_baseline_options(parser: argparse.ArgumentParser, rounds: int, rounds_help: str) -> None:
    """``--baseline COMMIT`` and ``--rounds N`` as every side-by-side benchmark takes them
    (``rounds_help``: what one round is, the default appended)."""
    parser.add_argument("--baseline", metavar="COMMIT",
                        help="also measure this commit's tree (a temporary worktree), the two "
                             "alternating round by round")
    parser.add_argument("--rounds", type=int, default=rounds,
                        help=f"{rounds_help} (default %(default)s)")
