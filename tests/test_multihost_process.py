"""Runs ``tests/test_multihost.py`` in a fresh Python process (see its docstring for why) and
passes when every one of its tests passed; their output is printed here."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from twinslam.node_hosts.netns import unavailable_reason

REPO = Path(__file__).resolve().parents[1]
_why_not = unavailable_reason()


@pytest.mark.skipif(_why_not is not None, reason=f"multi-host tests: {_why_not}")
def test_the_multihost_tests_pass_in_a_fresh_process() -> None:
    env = dict(os.environ, TWINSLAM_MULTIHOST_PROCESS="1")
    done = subprocess.run([sys.executable, "-m", "pytest", "-v", "-rs", "-p", "no:cacheprovider",
                           "tests/test_multihost.py"], cwd=REPO, env=env, text=True,
                          capture_output=True, timeout=1500)
    print(done.stdout[-20000:])
    assert done.returncode == 0, done.stdout[-8000:] + done.stderr[-2000:]
    assert " passed" in done.stdout.splitlines()[-1]
