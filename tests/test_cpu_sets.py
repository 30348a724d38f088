"""Node processes held to cores of their own (emulated hosts of a given size): the CPU lists
users write as ``taskset -c`` does, refused where they name no core or one this machine does
not give, and a process started held to a set runs there — every thread it starts too."""

from __future__ import annotations

import os
import sys

import pytest

import bench.edge_scaling as edge_scaling
from twinslam.hosts import cpu_sets
from twinslam.hosts.loopback import LoopbackDomain

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="Linux's CPU affinity")


@pytest.mark.parametrize(("text", "cores"), [("0", {0}), ("0-1", {0, 1}), ("2,3", {2, 3}),
                                              ("0-3,8", {0, 1, 2, 3, 8}), (" 1 , 0 ", {0, 1})])
def test_a_cpu_list_names_the_cores_taskset_would_and_reads_back(text: str,
                                                                 cores: set[int]) -> None:
    assert cpu_sets.parse_cpu_list(text) == cores
    assert cpu_sets.parse_cpu_list(cpu_sets.format_cpu_list(frozenset(cores))) == cores


def test_runs_of_neighbouring_cores_are_written_as_ranges() -> None:
    assert cpu_sets.format_cpu_list(frozenset({8, 0, 1, 2, 3, 5})) == "0-3,5,8"


@pytest.mark.parametrize("text", ["", "a", "1-", "3-1", "-2", "0,,1"])
def test_a_list_that_names_no_core_is_refused_with_the_form_it_should_have(text: str) -> None:
    with pytest.raises(cpu_sets.CpuSetError, match=r"0-1|no range"):
        cpu_sets.parse_cpu_list(text)


def test_a_core_this_machine_does_not_give_is_refused_by_name() -> None:
    beyond = max(os.sched_getaffinity(0)) + 1
    with pytest.raises(cpu_sets.CpuSetError, match=f"cores {beyond} are not among"):
        cpu_sets.usable(frozenset({0, beyond}))
    assert cpu_sets.usable(frozenset(os.sched_getaffinity(0))) == os.sched_getaffinity(0)


def test_the_sets_cycle_over_the_processes() -> None:
    a, b = frozenset({0, 1}), frozenset({2, 3})
    assert cpu_sets.cycled([a, a, b, b], 4) == [a, a, b, b]
    assert cpu_sets.cycled([a, b], 3) == [a, b, a]
    assert cpu_sets.cycled([], 2) == [None, None]


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2,
                    reason="one usable core: a held process is not told apart")
def test_a_process_started_held_to_a_core_runs_there_and_so_do_its_threads() -> None:
    """The edge's DDS threads, math pools and loop worker start after the process does: the
    set is taken before the child runs anything, and every thread inherits it."""
    core = min(os.sched_getaffinity(0))
    probe = ("import os, threading\n"
             "cores = lambda: format_cpu_list(frozenset(os.sched_getaffinity(0)))\n"
             "seen = []\n"
             "t = threading.Thread(target=lambda: seen.append(cores()))\n"
             "t.start(); t.join()\n"
             "print(cores(), seen[0], flush=True)\n")
    setup = "from twinslam.hosts.cpu_sets import format_cpu_list\n"
    with LoopbackDomain() as domain:
        held = domain.spawn(["-c", setup + probe], **cpu_sets.held_to(frozenset({core})))
        free = domain.spawn(["-c", setup + probe], **cpu_sets.held_to(None))
        out_held, _ = held.communicate(timeout=60)
        out_free, _ = free.communicate(timeout=60)
    assert out_held.split() == [str(core), str(core)]
    every = cpu_sets.format_cpu_list(frozenset(os.sched_getaffinity(0)))
    assert out_free.split() == [every, every]


def test_the_fleet_bench_refuses_cores_it_cannot_use_before_recording(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    recorded: list[object] = []
    monkeypatch.setattr(edge_scaling, "record", lambda folder: recorded.append(folder))
    beyond = max(os.sched_getaffinity(0)) + 1
    for argv, says in ((["--edge-cores", f"0 {beyond}"], f"cores {beyond} are not among"),
                       (["--edge-cores", "0-x"], "a CPU list is cores and ranges"),
                       (["--edge-cores", "0", "--device-cores", "0"], "overlap the edges'")):
        monkeypatch.setattr(sys, "argv", ["edge_scaling", "--devices", "2", *argv])
        with pytest.raises(SystemExit) as exited:
            edge_scaling.main()
        assert exited.value.code == 2 and not recorded
        assert says in capsys.readouterr().err
