"""``ros2 run`` readiness, tested the way a ROS developer builds: ``make`` builds the
``twinslam_msgs`` interface package with colcon into the venv, which stands for the ROS
installation (an underlay: /opt/ros/jazzy and the message packages installed with it), and
colcon builds ``twinslam`` over it into a fresh workspace with ``--symlink-install`` (the
Python sources linked, not copied: edits need no rebuild, and the numba kernels ``make``
compiled for them are found); every executable is started through the path
``ament_index_python`` resolves for it — what ``ros2 run twinslam <exe>`` does (ros2cli itself
is not on PyPI) — from a shell that sourced the workspace's ``setup.bash``. A copying ``colcon
build`` installs new source files, whose kernels ``twinslam precompile`` compiles once
(README; ``make`` runs that command)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from twinslam.hosts.fastdds import ros_env
from twinslam.hosts.loopback import DomainClaim

REPO = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)
EXECUTABLES = {"device_tracker", "edge_mapper", "sequence_player", "twinslam", "udt_node"}

pytestmark = [pytest.mark.slow(seconds=40),
              pytest.mark.skipif(shutil.which("colcon", path=str(VENV / "bin")) is None,
                                 reason="colcon is not installed in this environment")]
_claims: list[DomainClaim] = []


def _domain_id() -> int:
    """The private domain of the workspace's nodes, claimed at first use for the process."""
    if not _claims:
        _claims.append(DomainClaim())
    return _claims[0].domain_id


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    ws = tmp_path_factory.mktemp("ws")
    env = dict(os.environ, PATH=f"{VENV / 'bin'}:{os.environ['PATH']}",
               AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV))
    started = time.monotonic()
    done = subprocess.run(
        [str(VENV / "bin" / "colcon"), "--log-base", str(ws / "log"), "build", "--paths",
         str(REPO), "--build-base", str(ws / "build"),
         "--install-base", str(ws / "install"), "--symlink-install",
         "--cmake-args", "-DBUILD_TESTING=OFF",
         f"-DPython3_EXECUTABLE={sys.executable}"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    print(f"\ncolcon built twinslam in {time.monotonic() - started:.0f} s")
    return ws


def _in_workspace(ws: Path, command: str, **popen: object) -> subprocess.Popen[str]:
    """``command`` in a shell that sourced the workspace, on a private domain."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}
    # the venv stands for /opt/ros/jazzy: its python3 has rclpy, its prefix the ROS packages
    env.update(ros_env(_domain_id()), AMENT_PREFIX_PATH=str(VENV),
               PATH=f"{VENV / 'bin'}:{os.environ['PATH']}")
    script = f". {ws / 'install' / 'setup.bash'} && cd {ws} && {command}"
    return subprocess.Popen(["bash", "-c", script], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **popen)


def _resolve(ws: Path) -> tuple[Path, set[str], str]:
    code = ("from ament_index_python.packages import get_package_prefix as p; import "
            "twinslam_msgs, edge_mapper; print(p('twinslam')); print(twinslam_msgs.__file__); "
            "print(edge_mapper.__file__)")
    out, err = _in_workspace(ws, f"python3 -c \"{code}\"").communicate(timeout=120)
    assert out, err
    prefix, msgs_file, edge_file = out.split()
    lib = Path(prefix) / "lib" / "twinslam"
    # the messages from the underlay, where make installed them with colcon; the nodes from
    # the workspace (not the venv's editable install), linked to this checkout's sources
    assert Path(msgs_file).is_relative_to(VENV), out
    assert (VENV / "share" / "colcon-core" / "packages" / "twinslam_msgs").is_file()
    assert Path(edge_file).is_relative_to(ws), out
    assert Path(edge_file).resolve() == REPO / "edge_mapper" / "__init__.py", out
    return lib, {p.name for p in lib.iterdir()}, prefix


def test_colcon_workspace_resolves_and_runs_every_executable(workspace: Path) -> None:
    lib, executables, _prefix = _resolve(workspace)
    assert executables == EXECUTABLES            # `ros2 pkg executables twinslam`
    player = _in_workspace(workspace, f"{lib / 'sequence_player'} --ros-args "
                           "-p sequence:=synthetic:5 -p rate:=5.0")
    _, err = player.communicate(timeout=120)
    assert player.returncode == 0 and "done: 5 frames published" in err, err[-2000:]
    ready = {"edge_mapper": "listening on", "device_tracker": "waiting for",
             "udt_node": "listening on"}
    procs = {name: _in_workspace(workspace, f"exec {lib / name}", start_new_session=True)
             for name in ready}                                   # started side by side
    try:
        for name, proc in procs.items():
            seen = ""
            deadline = time.monotonic() + 120
            assert proc.stderr is not None
            while time.monotonic() < deadline and ready[name] not in seen and \
                    proc.poll() is None:
                seen += proc.stderr.readline()
            os.killpg(proc.pid, signal.SIGINT)
            _, rest = proc.communicate(timeout=30)
            assert ready[name] in seen, f"{name}: {(seen + rest)[-2000:]}"
            assert proc.returncode == 0, f"{name} exited {proc.returncode}: {rest[-2000:]}"
    finally:                          # a failed check leaves no node running behind it
        for proc in procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
    cli = _in_workspace(workspace, f"{lib / 'twinslam'} --help")
    out, err = cli.communicate(timeout=60)
    assert cli.returncode == 0 and "launch" in out, err
