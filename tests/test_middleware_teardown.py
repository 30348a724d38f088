"""A node's process whose teardown is stuck in C code with the interpreter held — where a DDS
participant's deletion deadlocks in Fast DDS — ends on its own: it prints the stuck thread's
stack and exits with code 1 once the bound has passed; a teardown that ends in time prints
nothing of it."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from twinslam.hosts.loopback import REPO_ROOT
from twinslam.node_runtime.middleware_teardown import (
    TIMEOUT_MARK,
    ended_as_asked,
    stuck_in_teardown,
)

#: a teardown under a 0.5 s bound: stuck in C with the interpreter held (a regular expression
#: that backtracks for hours stands in for the deadlocked deletion), or done at once
TEARDOWN = """
import re, sys
from twinslam.node_runtime.middleware_teardown import teardown_bound
with teardown_bound(0.5):
    if sys.argv[1] == "stuck":
        re.match(r"(a+)+$", "a" * 40 + "b")
print("ended", flush=True)
"""


def _teardown(kind: str) -> tuple[subprocess.CompletedProcess[str], float]:
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-c", TEARDOWN, kind], capture_output=True,
                          text=True, cwd=REPO_ROOT, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    return done, time.monotonic() - started


def test_a_teardown_stuck_with_the_interpreter_held_ends_the_process_at_its_bound() -> None:
    done, took = _teardown("stuck")
    assert done.returncode == 1 and "ended" not in done.stdout
    assert TIMEOUT_MARK in done.stderr and "<module>" in done.stderr, done.stderr
    assert took < 30.0                       # the bound, not the hours the match would take


def test_a_teardown_that_ends_in_time_leaves_no_trace_of_the_bound() -> None:
    done, _ = _teardown("quick")
    assert done.returncode == 0 and done.stdout == "ended\n" and done.stderr == ""


def test_a_log_tells_a_destruction_stuck_at_the_bound_from_other_ends() -> None:
    stuck = ("[INFO] [udt_node]: stopping: 1 slots learned from, 0 refused\n"
             "Timeout (0:00:10)!\nThread 0x00007f1c (most recent call first):\n"
             '  File "rclpy/node.py", line 1965 in destroy_node\n'
             '  File "twinslam/node_runtime/node_main.py", line 190 in run_node\n')
    assert stuck_in_teardown(stuck)
    # a node (or a player done playing) that ended so ended as asked; with another code, or
    # code 1 for another reason, it did not
    assert ended_as_asked(1, stuck) and ended_as_asked(0, "")
    assert not ended_as_asked(2, stuck) and not ended_as_asked(1, "Traceback (most recent")
    assert not stuck_in_teardown("[INFO] [udt_node]: stopping: 1 slots learned from\n")
    # the bound's report from somewhere else than the node's destruction is not this deadlock
    assert not stuck_in_teardown("Timeout (0:00:10)!\n  File \"x.py\", line 3 in close\n")
