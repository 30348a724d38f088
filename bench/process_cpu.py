"""Where a command's CPU goes, by process kind: every process it starts, the nodes forked from
the fork servers included, which ``getrusage`` and ``bench.suite_cpu`` cannot count (a forked
node is the fork server's child, and the server is killed, not waited for).

    .venv/bin/python -m bench.process_cpu [--every 0.3] [--top 20] [--threads] -- COMMAND [ARGS...]
    .venv/bin/python -m bench.process_cpu -- .venv/bin/python -m pytest -n 4 -p no:cacheprovider

The command runs in a session of its own; ``/proc`` is read every ``--every`` seconds, and each
process of that session is counted at the CPU time (user + system) it last showed
(``--threads``: each of its threads, the group split into the process's main thread and its
other threads by name — a Python thread carries the process's name unless it names itself:
an edge's loop closer (``loop-closer_0``), its keyframe database's words (``place-words``)
and its checkpoint writer (``checkpoints``) do (:mod:`twinslam.thread_names`), as DDS's
threads do). A process
that lives less than one interval may be missed, and one is counted up to an interval short of
its end: the total is a lower bound, compared with the command's own children's total (what
the kernel counts for the processes that were waited for). Processes are grouped by name (a
forked node names itself: ``device_tracker``, ``sequence_player``, ``edge_mapper``), a Python
process by the module it runs; a process already reaped to a zombie when first seen has no
command line left and counts under ``(exited)``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import time
from collections import Counter, defaultdict
from pathlib import Path

from twinslam.cli.console import HelpFormatter
from twinslam.node_runtime.thread_cpu import stat_cpu


def _group(comm: str, argv: list[str]) -> str:
    """A process's group: its name, or for a Python process the module or script it runs."""
    if not argv:
        return f"{comm} (exited)"
    if not comm.startswith("python"):
        return comm
    if "-m" in argv[:-1]:
        return f"python -m {argv[argv.index('-m') + 1]}"
    if "-c" in argv[:-1]:
        return f"python -c ({_snippet_kind(argv[argv.index('-c') + 1])})"
    scripts = [a for a in argv[1:] if a.endswith(".py") or "/bin/" in a]
    return f"python {Path(scripts[0]).name}" if scripts else "python"


#: what a ``python -c`` process is, by the code it was started with (the first match)
SNIPPETS = (("exec(eval(sys.stdin.readline()))", "pytest-xdist workers"),
            ("from multiprocessing.", "multiprocessing workers"))


def _snippet_kind(code: str) -> str:
    """The kind of a ``python -c CODE`` process: an xdist worker (execnet starts one with a
    bootstrap line), a worker of a process pool (multiprocessing's spawn), or another snippet
    (what a test or a benchmark runs in a process of its own)."""
    return next((kind for marker, kind in SNIPPETS if marker in code), "other snippets")


def _thread_label(comm: str, main: bool) -> str:
    """A thread's part of a group: the main thread, or the other threads by name (a name's
    trailing number dropped: DDS names its threads by index)."""
    if main:
        return "main thread"
    return f"threads {comm.rstrip('0123456789') or comm}#"


def _sample_threads(pid: int, group: str, seen: dict[object, tuple[float, str]]) -> None:
    """Each thread of process ``pid`` (of ``group``) at the CPU time it shows now."""
    try:
        tasks = list(os.scandir(f"/proc/{pid}/task"))
    except OSError:
        return
    for task in tasks:
        try:
            comm, _, cpu = stat_cpu(Path(task.path, "stat").read_text())
        except (OSError, ValueError):
            continue
        key = (pid, int(task.name))
        if key not in seen or cpu >= seen[key][0]:
            seen[key] = (cpu, f"{group} · {_thread_label(comm, int(task.name) == pid)}")


def _sample(session: int, seen: dict[object, tuple[float, str]], threads: bool = False
            ) -> None:
    """The CPU seconds and group of every process of ``session`` now (``threads``: of
    every thread of theirs, keyed by (pid, tid))."""
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text()
            argv = Path(entry.path, "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        comm, fields, cpu = stat_cpu(stat)
        if int(fields[3]) != session:        # field 6 of stat: the session id
            continue
        args = [a.decode(errors="replace") for a in argv if a]
        pid = int(entry.name)
        old = seen.get(pid)
        group = _group(comm, args) if args or old is None else old[1]
        if pid not in seen or cpu >= seen[pid][0]:
            seen[pid] = (cpu, group)
        if threads:
            _sample_threads(pid, group, seen)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=HelpFormatter)
    parser.add_argument("--every", type=float, default=0.3,
                        help="seconds between two readings of /proc (default %(default)s)")
    parser.add_argument("--top", type=int, default=20,
                        help="groups shown, the costliest first (default %(default)s)")
    parser.add_argument("--threads", action="store_true",
                        help="split each group by thread: the main thread, the others by "
                             "name")
    parser.add_argument("command", nargs=argparse.REMAINDER,
                        help="the command, after --")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no command given (put it after --)")
    if args.every <= 0 or args.top < 1:
        parser.error("--every must be above 0 and --top at least 1")
    start = time.monotonic()
    proc = subprocess.Popen(command, start_new_session=True)
    seen: dict[object, tuple[float, str]] = {}     #: pid, or (pid, tid), → (CPU s, group)
    while proc.poll() is None:
        _sample(proc.pid, seen, args.threads)
        time.sleep(args.every)
    wall = time.monotonic() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    groups: defaultdict[str, float] = defaultdict(float)     #: CPU seconds a group
    counts: Counter[str] = Counter()
    for key, (cpu, group) in seen.items():
        if isinstance(key, tuple) == args.threads:       # threads, or whole processes
            groups[group] += cpu
            counts[group] += 1
    total = sum(groups.values())
    processes = sum(1 for key in seen if not isinstance(key, tuple))
    print(f"\nexit {proc.returncode}; {wall:.0f} s wall; CPU seen in {processes} processes "
          f"{total:.0f} s (a lower bound); the waited-for children's own count "
          f"{usage.ru_utime + usage.ru_stime:.1f} s")
    unit = "threads" if args.threads else "procs"
    print(f"{'CPU s':>8} {'share':>6} {unit:>7}  group")
    for group, cpu in sorted(groups.items(), key=lambda gc: -gc[1])[:args.top]:
        print(f"{cpu:8.1f} {100 * cpu / max(total, 1e-9):5.1f}% {counts[group]:7d}  {group}")
    raise SystemExit(proc.returncode)


if __name__ == "__main__":
    main()
