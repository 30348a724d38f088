"""``bench.process_cpu``: a command's CPU by process kind, counting the processes it never
waited for (what a node forked from a fork server is) — the part of ``make test``'s CPU that
``bench.suite_cpu`` cannot see."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

SPIN = ("import sys, time\nend = time.process_time() + 1.0\n"
        "while time.process_time() < end:\n    pass\nopen(sys.argv[1], 'w').close()\n")
#: starts spin.py as a grandchild nobody waits for (its parent exits at once), then waits
#: for the file spin.py writes when done, at most 60 s
DRIVER = """import os, sys, time
done = sys.argv[2]
child = os.fork()
if child == 0:
    if os.fork() == 0:
        os.execv(sys.executable, [sys.executable, sys.argv[1], done])
    os._exit(0)
os.waitpid(child, 0)
end = time.monotonic() + 60
while not os.path.exists(done) and time.monotonic() < end:
    time.sleep(0.05)
time.sleep(0.3)
sys.exit(0 if os.path.exists(done) else 3)
"""


def test_a_process_nobody_waited_for_is_counted_under_its_name(tmp_path: Path) -> None:
    (tmp_path / "spin.py").write_text(SPIN, encoding="utf-8")
    (tmp_path / "driver.py").write_text(DRIVER, encoding="utf-8")
    run = subprocess.run([sys.executable, "-m", "bench.process_cpu", "--every", "0.1", "--",
                          sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "spin.py"),
                          str(tmp_path / "done")], cwd=REPO, capture_output=True, text=True,
                         timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    row = next(line for line in run.stdout.splitlines() if line.endswith("python spin.py"))
    assert float(row.split()[0]) >= 0.7, run.stdout
    # the kernel's count of waited-for children misses it: the grandchild was never waited for
    waited = re.search(r"children's own count (\d+\.\d) s", run.stdout)
    assert waited is not None and float(waited.group(1)) < 0.7, run.stdout


def test_a_command_is_required() -> None:
    run = subprocess.run([sys.executable, "-m", "bench.process_cpu", "--"], cwd=REPO,
                         capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert run.returncode == 2 and "no command given" in run.stderr


#: a main thread that spins 0.4 s of its own CPU while a second thread spins 1.2 s of its own;
#: both stay alive, idle, for half a second after (a thread is read while it lives)
TWO_THREADS = ("import threading, time\n"
               "def spin(seconds):\n"
               "    end = time.thread_time() + seconds\n"
               "    while time.thread_time() < end:\n"
               "        pass\n"
               "spun, leave = threading.Event(), threading.Event()\n"
               "def other_thread():\n"
               "    spin(1.2)\n"
               "    spun.set()\n"
               "    leave.wait(60)\n"
               "other = threading.Thread(target=other_thread)\n"
               "other.start()\nspin(0.4)\nspun.wait(60)\ntime.sleep(0.5)\n"
               "leave.set()\nother.join()\n")


def test_threads_split_a_process_into_its_main_thread_and_the_others(tmp_path: Path) -> None:
    """An edge's CPU is its slot thread's and its loop closer's: ``--threads`` tells them
    apart."""
    (tmp_path / "two.py").write_text(TWO_THREADS, encoding="utf-8")
    run = subprocess.run([sys.executable, "-m", "bench.process_cpu", "--every", "0.1",
                          "--threads", "--", sys.executable, str(tmp_path / "two.py")],
                         cwd=REPO, capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    rows = {line.split(None, 3)[3]: float(line.split()[0])
            for line in run.stdout.splitlines() if "python two.py · " in line}
    main = rows.pop("python two.py · main thread")
    (others,) = rows.values()
    assert 0.3 <= main < 0.9 and others >= 1.1, run.stdout


def test_the_fleet_bench_reads_one_threads_cpu_apart_from_its_process() -> None:
    """``bench.edge_scaling``'s ``slot thr``: an edge's main thread's CPU, apart from its loop
    closer's: a thread that spins shows in the process's count, not the main thread's."""
    import threading
    import time

    from bench.edge_scaling import cpu_seconds

    pid, main = os.getpid(), threading.get_native_id()

    def spin() -> None:
        end = time.thread_time() + 0.6
        while time.thread_time() < end:
            pass

    main0, whole0 = cpu_seconds(pid, main), cpu_seconds(pid)
    worker = threading.Thread(target=spin)
    worker.start()
    worker.join()
    assert cpu_seconds(pid, main) - main0 < 0.3
    assert cpu_seconds(pid) - whole0 >= 0.5


def test_python_c_processes_are_told_apart_by_what_they_run() -> None:
    """The suite's xdist workers, a sweep's pool workers and a test's own snippets each have a
    row: together they were 41 % of a clean clone's CPU, under one name."""
    from bench.process_cpu import _group

    python = "/venv/bin/python"
    assert _group("python", [python, "-u", "-c", "import sys;exec(eval(sys.stdin.readline()))"]
                  ) == "python -c (pytest-xdist workers)"
    spawned = "from multiprocessing.spawn import spawn_main; spawn_main(tracker_fd=5)"
    assert _group("python3.11", [python, "-c", spawned, "--multiprocessing-fork"]
                  ) == "python -c (multiprocessing workers)"
    assert _group("python", [python, "-c", "import runpy\nrunpy.run_module('bench.place_walks')"]
                  ) == "python -c (other snippets)"
    assert _group("python", [python, "-m", "device_tracker.node", "--ros-args"]
                  ) == "python -m device_tracker.node"
