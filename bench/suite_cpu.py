"""What each test of the suite costs in CPU, where ``make test``'s time goes on two cores.

The suite runs on parallel workers that fill the host's cores (``make test``: four on two), so
its wall time is its CPU time over the cores, and pytest's ``--durations`` — wall time under
that load — does not say which tests cost the CPU. This is a pytest plugin that writes each
test's CPU seconds (its worker's own and those of the processes it started and waited for:
``getrusage``'s children; a node the test forked through the fork server, or a Ray worker, is
not its child and is not counted) with its wall seconds, one JSON line a test, and a summary
of such a file by test and by module::

    TWINSLAM_SUITE_CPU=/tmp/cpu.jsonl PYTHONPATH=. .venv/bin/python -m pytest -n 4 \
        -p bench.suite_cpu
    python -m bench.suite_cpu /tmp/cpu.jsonl [--top 30]

A test's fixtures count in the first test that sets them up.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from collections import Counter
from collections.abc import Generator
from pathlib import Path
from typing import Any

import pytest

from twinslam.cli.console import HelpFormatter

#: the file the plugin appends to
OUT_ENV = "TWINSLAM_SUITE_CPU"


def _cpu_s() -> tuple[float, float]:
    """(this process's CPU seconds, its waited-for children's)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None
                            ) -> Generator[None, Any, None]:
    """Around each test (set-up, call, teardown): its CPU and wall seconds, appended."""
    own0, children0 = _cpu_s()
    wall0 = time.monotonic()
    yield
    own1, children1 = _cpu_s()
    out = os.environ.get(OUT_ENV)
    if not out:
        return
    with open(out, "a", encoding="utf-8") as fh:
        fh.write(json.dumps({"test": item.nodeid, "own_s": own1 - own0,
                             "children_s": children1 - children0,
                             "wall_s": time.monotonic() - wall0,
                             "worker": os.environ.get("PYTEST_XDIST_WORKER", "")}) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     epilog=__doc__.split("\n", 2)[2],
                                     formatter_class=HelpFormatter)
    parser.add_argument("file", type=Path, help="the JSON lines the plugin wrote")
    parser.add_argument("--top", type=int, default=30, help="tests and modules listed")
    args = parser.parse_args()
    try:
        rows = [json.loads(line) for line in args.file.read_text(encoding="utf-8").splitlines()
                if line.strip()]
    except (OSError, ValueError) as exc:
        raise SystemExit(f"{args.file}: not the plugin's JSON lines ({exc})") from None
    cpu = {r["test"]: r["own_s"] + r["children_s"] for r in rows}
    total = sum(cpu.values())
    print(f"{len(rows)} tests, {total:.0f} s of CPU counted, {sum(r['wall_s'] for r in rows):.0f}"
          f" s of wall summed over the workers")
    print(f"{'CPU s':>7} {'own':>6} {'children':>8} {'wall s':>7}  test")
    for r in sorted(rows, key=lambda r: -cpu[r["test"]])[:args.top]:
        print(f"{cpu[r['test']]:7.1f} {r['own_s']:6.1f} {r['children_s']:8.1f} "
              f"{r['wall_s']:7.1f}  {r['test']}")
    modules: Counter[str] = Counter()
    for test, seconds in cpu.items():
        modules[test.split("::")[0]] += seconds
    print(f"\n{'CPU s':>7} {'share':>6}  module")
    for module, seconds in modules.most_common(args.top):
        print(f"{seconds:7.1f} {seconds / max(total, 1e-9):6.1%}  {module}")


if __name__ == "__main__":
    main()
