"""Runs ``tests/test_multihost.py`` in fresh Python processes (see its docstring for why: Fast DDS
takes a process's network interfaces from its first participant) and passes when every one of
their tests passed; their output is printed here.

The multi-host tests are split into a few processes that parallel workers run side by side, each
holding tests that together take about as long; a test of that module missing from every
process, or named twice, fails here instead of silently not running.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from twinslam.hosts.netns import unavailable_reason

REPO = Path(__file__).resolve().parents[1]
MODULE = REPO / "tests" / "test_multihost.py"
_why_not = unavailable_reason()

#: the fresh processes and the tests each runs
PROCESSES = {
    "twin-on-its-own-host": ["test_twin_absent_edge_falls_back_and_returns_when_latents_flow"],
    "edge-restart-and-shaped-cable": [
        "test_edge_host_node_killed_and_restarted_restores_its_map",
        "test_device_uplink_through_tc_follows_the_configured_rate"],
    "cables-and-hosts": [
        "test_hosts_have_their_own_address_and_nothing_else",
        "test_hosts_command_builds_and_removes_the_three_hosts",
        "test_link_down_for_5_s_device_tracks_on_and_uploads_resume",
        "test_5_percent_loss_reliable_topics_deliver_best_effort_images_degrade",
        "test_two_devices_on_hosts_of_their_own_share_one_edge_each_uplink_its_own_cable"],
}


def _tests_of_the_module() -> list[str]:
    tree = ast.parse(MODULE.read_text(encoding="utf-8"))
    return [node.name for node in tree.body
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_")]


def test_every_multihost_test_runs_in_exactly_one_process() -> None:
    named = [name for names in PROCESSES.values() for name in names]
    assert sorted(named) == sorted(_tests_of_the_module())


@pytest.mark.slow(seconds=110)
@pytest.mark.timeout(900)               # its tests run one after another, each within 300 s
@pytest.mark.skipif(_why_not is not None, reason=f"multi-host tests: {_why_not}")
@pytest.mark.parametrize("process", sorted(PROCESSES))
def test_the_multihost_tests_pass_in_a_fresh_process(process: str) -> None:
    env = dict(os.environ, TWINSLAM_MULTIHOST_PROCESS="1")
    tests = [f"tests/test_multihost.py::{name}" for name in PROCESSES[process]]
    # -rfEs: the short summary names each failure with its assertion's first line
    done = subprocess.run([sys.executable, "-m", "pytest", "-v", "-rfEs", "-n0",
                           "-p", "no:cacheprovider", *tests], cwd=REPO, env=env, text=True,
                          capture_output=True, timeout=900)
    print(done.stdout[-20000:])
    # what failed first: a CI log that keeps only a message's first lines still says it
    failed = [line for line in done.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
    assert done.returncode == 0, "\n".join([*failed, done.stdout[-8000:], done.stderr[-2000:]])
    summary = done.stdout.splitlines()[-1]
    counts = {word: int(n) for n, word in re.findall(r"(\d+) (passed|skipped)", summary)}
    assert sum(counts.values()) == len(tests), summary
    # a skip is only allowed where this machine cannot lose packets (the reason is printed)
    skips = [line for line in done.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skips) == counts.get("skipped", 0)
    assert all("no way to lose packets" in line for line in skips), skips
