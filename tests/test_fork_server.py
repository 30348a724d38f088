"""Node processes forked from a preloaded server (twinslam.hosts.forked): each child is
the process ``python -m module`` would have been — its arguments, environment, working
directory, pipes, exit code and signals — and none outlives its server."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from twinslam.hosts.forked import ForkServer, ForkServerError, ForkServers
from twinslam.hosts.netns import unavailable_reason
from twinslam.live.node_fork_server import fork_servers

REPO = Path(__file__).resolve().parents[1]
PROBE = "tests.nodes.fork_probe"


def _env(**more: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.update(more)
    return env


def _first_line(proc: object) -> dict[str, object]:
    assert proc.stdout is not None       # type: ignore[attr-defined]
    return json.loads(proc.stdout.readline())   # type: ignore[attr-defined, no-any-return]


def test_a_forked_child_has_its_arguments_environment_pipes_and_exit_code(tmp_path: Path
                                                                         ) -> None:
    servers = ForkServers(PROBE, frozenset({"probe"}), tmp_path)
    try:
        env = _env(ROS_DOMAIN_ID="117")
        proc = servers.spawn(["-m", "probe", "exit", "3"], env)
        assert proc is not None
        seen = _first_line(proc)
        assert proc.wait(timeout=20) == 3
        server = servers.server_for(env)
        assert seen["argv"] == ["probe", "exit", "3"] and seen["ros"] == "117"
        assert seen["cwd"] == str(tmp_path)
        assert seen["pid"] == proc.pid and seen["ppid"] == server._proc.pid
        assert seen["preloaded_by"] == server._proc.pid       # forked, not started anew
        assert proc.stderr is not None and proc.stderr.read() == "probe on stderr\n"
        # a per-child ROS setting is served by the same server, and so is the next test's
        # name (pytest's PYTEST_CURRENT_TEST), which the child sees as its own; an
        # import-time setting is not
        other_domain = _env(ROS_DOMAIN_ID="118")
        assert servers.server_for(other_domain) is server
        next_test = _env(ROS_DOMAIN_ID="118", PYTEST_CURRENT_TEST="tests/x.py::test_y (call)")
        assert servers.server_for(next_test) is server
        proc = servers.spawn(["-m", "probe", "exit", "0"], next_test)
        assert proc is not None and proc.wait(timeout=20) == 0
        assert _first_line(proc)["test"] == "tests/x.py::test_y (call)"
        assert servers.server_for(_env(PROBE_MARKER="x")) is not server
        # what the server did not preload is left to the caller
        assert servers.spawn(["-m", "json.tool"], env) is None
        assert servers.spawn(["tests/nodes/fork_probe.py"], env) is None
    finally:
        servers.close()


@pytest.mark.skipif(unavailable_reason() is not None,
                    reason=f"network namespaces: {unavailable_reason()}")
def test_a_child_forked_for_a_host_lives_in_the_hosts_network_namespace(tmp_path: Path
                                                                       ) -> None:
    """A node of a ``--hosts`` run forked from the one server: in the host's namespace, as
    ``ip netns exec`` would have run it, its server and its siblings in this machine's."""
    name = f"twinslam-fork-{os.getpid()}"
    subprocess.run(["ip", "netns", "add", name], check=True)
    server = ForkServer(PROBE, _env(), tmp_path)
    try:
        there = subprocess.run(["ip", "netns", "exec", name, "readlink", "/proc/self/ns/net"],
                               capture_output=True, text=True, check=True).stdout.strip()
        here = os.readlink("/proc/self/ns/net")
        assert there != here
        inside = server.spawn("probe", ["exit", "0"], _env(), tmp_path,
                              netns=f"/run/netns/{name}")
        outside = server.spawn("probe", ["exit", "0"], _env(), tmp_path)
        assert _first_line(inside)["netns"] == there and inside.wait(timeout=20) == 0
        assert _first_line(outside)["netns"] == here and outside.wait(timeout=20) == 0
        assert os.readlink(f"/proc/{server._proc.pid}/ns/net") == here
    finally:
        server.close()
        subprocess.run(["ip", "netns", "delete", name], check=False)


def test_a_signalled_child_reports_the_signal_as_popen_does(tmp_path: Path) -> None:
    server = ForkServer(PROBE, _env(), tmp_path)
    try:
        proc = server.spawn("probe", ["wait", "0"], _env(), tmp_path)
        _first_line(proc)
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=0.2)
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == -signal.SIGTERM
        proc.kill()                     # after the exit: no signal to a pid that may be reused
    finally:
        server.close()


def test_no_child_outlives_its_server(tmp_path: Path) -> None:
    server = ForkServer(PROBE, _env(), tmp_path)
    proc = server.spawn("probe", ["wait", "0"], _env(), tmp_path)
    _first_line(proc)
    server._proc.kill()
    assert proc.wait(timeout=20) == -signal.SIGKILL
    deadline = time.monotonic() + 10          # the kernel kills it as its parent goes
    while _running(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(proc.pid)
    server.close()


def _running(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "zombie" not in status.lower()


def test_a_server_that_cannot_start_says_why(tmp_path: Path) -> None:
    servers = ForkServers("tests.nodes.no_such_server", frozenset({"probe"}), tmp_path)
    with pytest.raises(ForkServerError, match="No module named"):
        servers.server_for(_env())
    assert servers.spawn(["-m", "probe", "exit", "0"], _env()) is None   # the caller starts it


def test_the_launchers_edge_is_forked_and_refuses_a_bad_parameter_as_it_would_alone() -> None:
    """The real fork server: the edge's main parses its ROS arguments and exits with 2 and the
    reason, as ``python -m edge_mapper.node`` does (tests/test_edge_parameters.py)."""
    proc = fork_servers(REPO).spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=bogus"],
                       _env(ROS_DOMAIN_ID="119"))
    assert proc is not None
    assert proc.wait(timeout=60) == 2
    assert proc.stderr is not None
    log = proc.stderr.read()
    assert "unknown policy 'bogus'" in log and "Traceback" not in log

