"""How every command talks to its user: errors on stderr with the exit code they mean, and
progress lines stamped with the seconds since the command started."""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, TypeVar

from twinslam.sweeps import TaskFailure

#: the subparsers object every command registers itself with (argparse names no public type,
#: and its class is generic only to type checkers)
if TYPE_CHECKING:
    Subparsers = argparse._SubParsersAction[argparse.ArgumentParser]
else:
    Subparsers = argparse._SubParsersAction

#: exit code of a command refused before it ran (bad options or input), as argparse's own
USAGE_ERROR = 2

R = TypeVar("R")


def error(message: object, code: int = USAGE_ERROR) -> int:
    """Print ``error: message`` on stderr and return ``code`` for the command to return."""
    print(f"error: {message}", file=sys.stderr)
    return code


def failed_tasks(failures: Sequence[TaskFailure], what: str, where: str) -> int:
    """0 when no task failed, else 1 after naming each failed ``what`` and its last line,
    and ``where`` its traceback is."""
    if not failures:
        return 0
    return error(f"{len(failures)} {what} failed: " + "; ".join(
        f"{f.task} ({f.last_line})" for f in failures) + f" — tracebacks in {where}", 1)


def warn_aliases(names: Iterable[str], aliases: Mapping[str, str]) -> None:
    """A deprecation line on stderr for each old name used (it still works)."""
    for name in dict.fromkeys(names):
        if name in aliases:
            print(f"note: {name!r} is the old name of {aliases[name]!r} (deprecated; it still "
                  "works)", file=sys.stderr)


def elapsed_progress() -> Callable[[str], None]:
    """A progress printer for long work: each line on stderr after the seconds elapsed."""
    t0 = time.monotonic()

    def progress(line: str) -> None:
        print(f"[{time.monotonic() - t0:7.1f} s] {line}", file=sys.stderr, flush=True)

    return progress


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every option's help ends with its default, unless the text already gives it; the
    reStructuredText literals of the docstrings a description is made of (````twinslam````)
    read as plain words."""

    def format_help(self) -> str:
        return re.sub(r"``([^`\n]+)``", r"\1", super().format_help())

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (action.option_strings and default is not None and default is not False
                and default != argparse.SUPPRESS and "default" not in text):
            text += " (default: %(default)s)"
        return text


def each_run(runs: list[Callable[[], R]]) -> list[R] | int:
    """Every run in turn (live runs of nodes); instead, the exit code when one is interrupted
    (130: its nodes were stopped) or fails (1, with the reason)."""
    done = []
    for one in runs:
        try:
            done.append(one())
        except KeyboardInterrupt:
            print("interrupted: nodes stopped", file=sys.stderr)
            return 130
        except RuntimeError as exc:
            return error(exc, 1)
    return done
