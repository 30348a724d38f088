"""The ROS 2 way in works from the venv ``make`` builds: ``ros2 pkg prefix twinslam`` finds the
package in the venv's ament index, ``ros2 launch twinslam twinslam_launch.py`` shows every
argument with a description and runs the pipeline, ``ros2 run twinslam NODE`` starts a node.

The ``ros2`` command line and ``launch`` / ``launch_ros`` are not on PyPI: these tests run where
they are importable beside the venv (docs/running.md, "The ROS 2 command line from the venv",
says how to get them) and are skipped elsewhere, with the reason."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from twinslam_msgs.msg import FrameSummaries

from msg_schemas import qos
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)
pytestmark = pytest.mark.skipif(
    not all(importlib.util.find_spec(m) for m in ("ros2cli", "ros2launch", "launch_ros")),
    reason="the ros2 command line and launch_ros are not importable here (not on PyPI; "
    "docs/running.md says how to put them beside the venv)")


def _ros2(*args: str, env: dict[str, str] | None = None, timeout: float = 120.0
          ) -> subprocess.CompletedProcess[str]:
    env = dict(env or os.environ, AMENT_PREFIX_PATH=str(VENV))
    return subprocess.run([sys.executable, "-c", "import sys; from ros2cli.cli import main; "
                           "sys.argv[0] = 'ros2'; sys.exit(main())", *args],
                          capture_output=True, text=True, timeout=timeout, env=env, check=False)


def test_the_package_is_in_the_venvs_ament_index_with_its_launch_file() -> None:
    prefix = _ros2("pkg", "prefix", "twinslam")
    assert prefix.returncode == 0 and Path(prefix.stdout.strip()) == VENV, prefix.stderr
    shown = _ros2("launch", "twinslam", "twinslam_launch.py", "--show-args")
    assert shown.returncode == 0, shown.stderr[-2000:]
    for name in ("params_file", "sequence", "policy", "map_source", "start", "end", "loop",
                 "every", "phase"):
        assert f"'{name}':" in shown.stdout, name
    assert "no description given" not in shown.stdout


def test_a_slot_that_does_not_split_every_ways_is_refused_before_any_node_starts() -> None:
    """``every:=7`` with the default device's 30-frame slot: the launch fails naming the
    slot and the parameter, and starts no process; so do an ``every`` that is no number and
    a ``rate`` that is not a positive number, each named."""
    with LoopbackDomain() as domain:
        refused = _ros2("launch", "twinslam", "twinslam_launch.py", "every:=7",
                        env=dict(domain.env))
    out = refused.stdout + refused.stderr
    assert refused.returncode != 0, out[-3000:]
    assert "does not split 7 ways" in out and "slot_frames" in out, out[-3000:]
    assert "process started" not in out, out[-3000:]
    with LoopbackDomain() as domain:
        refused = _ros2("launch", "twinslam", "twinslam_launch.py", "every:=two",
                        env=dict(domain.env))
    out = refused.stdout + refused.stderr
    assert refused.returncode != 0 and "every:=two: not a whole number" in out, out[-3000:]
    with LoopbackDomain() as domain:
        refused = _ros2("launch", "twinslam", "twinslam_launch.py", "rate:=0",
                        env=dict(domain.env))
    out = refused.stdout + refused.stderr
    assert refused.returncode != 0 and "rate:=0: rate must be a positive" in out, out[-3000:]


@pytest.mark.slow(seconds=60)
def test_ros2_launch_runs_the_pipeline_on_a_private_domain() -> None:
    """``ros2 launch twinslam twinslam_launch.py sequence:=synthetic:90 loop:=true rate:=2``:
    the device's slot summaries arrive, and Ctrl-C (SIGINT) stops every node. The player loops
    until the Ctrl-C: however long the probe takes to match on a loaded machine, summaries
    are still coming when it listens. ``rate:=2``, as a user types it, reaches the player as
    the double its parameter is (ROS reads ``2`` as an integer, which the player refuses)."""
    with LoopbackDomain() as domain:
        env = dict(domain.env, AMENT_PREFIX_PATH=str(VENV))
        proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; from ros2cli.cli import main; "
             "sys.argv[0] = 'ros2'; sys.exit(main())", "launch", "twinslam",
             "twinslam_launch.py", "sequence:=synthetic:90", "loop:=true", "rate:=2"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            domain.activate()
            ros = RosSession("ros2_launch_probe")
            summaries: list[FrameSummaries] = []
            ros.node.create_subscription(FrameSummaries, "/device/frame_summaries",
                                         summaries.append, qos.PROTOCOL)
            got = ros.spin_until(lambda: len(summaries) >= 2 or proc.poll() is not None, 120.0)
            ros.close()
        finally:
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=60)
        assert got and len(summaries) >= 2, out[-3000:]
        assert "process has died" not in out or "exit code -2" in out, out[-3000:]
