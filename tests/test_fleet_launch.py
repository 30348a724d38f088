"""``twinslam launch --devices N``: one edge and N devices as processes, a table per device,
their mean and Jain's index, and the settings that cannot run refused before anything starts
."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from twinslam.cli.main import main
from twinslam.hosts.forked import process_name
from twinslam.live.fleet import FleetConfig, device_sequence


def test_every_device_plays_its_own_walk() -> None:
    assert [device_sequence("synthetic:300", i, 3, 300, 0, 0, None) for i in range(3)] == [
        ("synthetic:300:0", 0), ("synthetic:300:1", 0), ("synthetic:300:2", 0)]
    assert [device_sequence("/data/7scenes", i, 4, 200, 0, 0, 1000)[1] for i in range(4)] == [
        0, 250, 500, 750]
    assert [device_sequence("/data/7scenes", i, 3, 200, 900, 100, 1000)[1]
            for i in range(3)] == [900, 0, 100]


def test_settings_that_cannot_run_are_refused_before_any_node_starts(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="V_total 8 is below 2 devices x 5 keyframes"):
        FleetConfig(2, 8, "equal", 5).check()
    assert main(["launch", "--devices", "2", "--allocator", "fifo", "--loopback"]) == 2
    assert "unknown allocator 'fifo'" in capsys.readouterr().err
    assert main(["launch", "--devices", "2", "--record", "bag", "--loopback"]) == 2
    assert "without --record" in capsys.readouterr().err


@pytest.mark.slow
def test_launch_serves_two_devices_from_one_edge_and_reports_each(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["launch", "--loopback", "--devices", "2", "--vmax-total", "12",
                 "--allocator", "motion", "--sequence", "synthetic:120", "--frames", "120",
                 "--policy", "lff", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0, out[-3000:]
    assert "lff, allocator motion: 2 devices" in out and "Jain's index" in out
    rows = {line.split()[0]: line.split() for line in out.splitlines()
            if line.split() and line.split()[0] in ("ar1", "ar2", "mean")}
    assert set(rows) == {"ar1", "ar2", "mean"}
    budgets = [float(rows[d][-2]) for d in ("ar1", "ar2")]
    assert all(0 < b <= 12 for b in budgets) and sum(budgets) <= 12 + 1e-9
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["lff_motion_ar1.png",
                                                            "lff_motion_ar2.png"]
    with (tmp_path / "fleet_runs.csv").open(encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["device"], r["allocator"], r["seed"]) for r in table] == [
        ("ar1", "motion", "0"), ("ar2", "motion", "0")]
    assert all(int(r["frames"]) > 0 and float(r["latency_ms_median"]) > 0 for r in table)


@pytest.mark.slow
def test_a_terminated_launch_stops_the_nodes_it_started(tmp_path: Path) -> None:
    """SIGTERM (``kill``, a scheduler) ends ``twinslam launch`` as Ctrl-C does: exit 130 and
    none of its node processes left running."""
    import os
    import signal
    import subprocess
    import sys
    import time

    cli = subprocess.Popen([sys.executable, "-m", "twinslam.cli.main", "launch", "--loopback",
                            "--sequence", "synthetic:900", "--frames", "900", "--policy", "lff",
                            "--out", str(tmp_path)], text=True, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, cwd=Path(__file__).resolve().parents[1])
    assert cli.stdout is not None
    seen, deadline = "", time.monotonic() + 120
    while "slot   0" not in seen and time.monotonic() < deadline and cli.poll() is None:
        seen += cli.stdout.readline()
    # the nodes: the launcher's children, or its fork server's (twinslam.live.node_fork_server)
    pids = [int(pid) for pid in os.listdir("/proc") if pid.isdigit()]
    servers = [pid for pid in pids if _parent(pid) == cli.pid]
    children = [pid for pid in pids if _parent(pid) in (cli.pid, *servers)]
    names = {_name(pid) for pid in children}
    assert "slot   0" in seen and {"edge_mapper", "device_tracker", "sequence_player"} <= names, \
        (seen[-2000:], names)
    cli.send_signal(signal.SIGTERM)
    _, err = cli.communicate(timeout=60)
    assert cli.returncode == 130 and "interrupted: nodes stopped" in err, err[-2000:]
    assert not [pid for pid in children if _alive(pid)], "nodes left running"


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return -1


def _name(pid: int) -> str:
    """A node process's name: the one a forked node gives itself, or its ``-m`` module's."""
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    except OSError:
        return ""
    if not comm.startswith("python"):
        return comm
    return process_name(argv[argv.index("-m") + 1]) if "-m" in argv[:-1] else comm


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"
