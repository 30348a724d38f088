"""The gate of every change as CI runs it: ``.ci/run`` (the README's ``make test``) on fresh
clones of this repository, one after another, each with the bundled data folder beside it —
the set-up from nothing (a warm pip cache is the machine's), the lint stage and the suite.

    .venv/bin/python -m bench.clean_clone [--runs 5] [--load 2] [--baseline REV] [--revision REV]
        [--csv FILE]

Prints, per run: the exit status, the wall time of ``.ci/run`` beside the CPU seconds its
processes used (user + system, every process it started: a slower change uses more CPU, a
busier machine only more wall time), the seconds a fixed pure-Python workload took on one core
just before the run (the machine's speed: a slower machine takes longer on it and on the
suite's CPU alike), the seconds pytest reported, the passed / failed / skipped counts and the
failed tests' ids; ``--load N`` keeps N busy loops
running beside the runs (a user doing other work on the machine), ``--baseline REV`` runs a
clone of REV before each run of HEAD (the side-by-side comparison a "no slower" claim needs),
``--csv`` appends one row a run. The clones live in a temporary folder removed after each
run; each run's output is kept in ``build/clean-clone/COMMIT-STAMP.log``.
"""

from __future__ import annotations

import argparse
import csv
import ctypes
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

from bench.paths import REPO

SHARED = REPO.parent / "shared"
FIELDS = ["date_utc", "commit", "load", "rc", "wall_s", "cpu_s", "probe_s", "pytest_s",
          "passed", "failed", "skipped", "failures"]
#: prctl's PR_SET_CHILD_SUBREAPER (linux/prctl.h)
PR_SET_CHILD_SUBREAPER = 36
#: iterations of the speed probe's loop: ~0.7 s of one core on the development machine
PROBE_ITERATIONS = 30_000_000


def _summary(log: str) -> dict[str, object]:
    """pytest's closing line and the FAILED lines of a run's output."""
    closing = re.findall(r"^=+ (.*) in ([\d.]+)s", log, flags=re.MULTILINE)
    counts = {word: int(n) for n, word in
              re.findall(r"(\d+) (passed|failed|skipped)", closing[-1][0] if closing else "")}
    failures = re.findall(r"^FAILED (\S+)", log, flags=re.MULTILINE)
    return {"pytest_s": float(closing[-1][1]) if closing else float("nan"),
            "passed": counts.get("passed", 0), "failed": counts.get("failed", len(failures)),
            "skipped": counts.get("skipped", 0), "failures": " ".join(failures)}


def clone_environment() -> dict[str, str]:
    """This process's environment without what this checkout's venv put into it. The ROS
    wheels' bootstrapper re-executes Python with ``LD_LIBRARY_PATH`` listing the venv's
    libraries and a guard variable set; inherited by a clone's processes, the guard stops
    their own bootstrap and the loader takes this venv's generated message libraries instead
    of the clone's — a run of an older commit then fails on a field a newer message has
    (measured: 14 failures, "'MapStats' object has no attribute 'archived_keyframes'")."""
    env = dict(os.environ)
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    env.pop("VIRTUAL_ENV", None)
    venv = str(REPO / ".venv")
    for name in ("LD_LIBRARY_PATH", "PATH"):
        kept = [part for part in env.get(name, "").split(os.pathsep)
                if part and not part.startswith(venv)]
        if kept:
            env[name] = os.pathsep.join(kept)
        else:
            env.pop(name, None)
    return env


def speed_probe() -> float:
    """Seconds a fixed pure-Python loop takes on one core (the interpreter's bytecode, as most
    of the suite's CPU is): what tells a slower machine from a slower change."""
    started = time.process_time()
    total = 0
    for i in range(PROBE_ITERATIONS):
        total += i & 7
    return round(time.process_time() - started, 3)


def adopt_orphans() -> None:
    """Make this process the reaper of the processes its runs leave orphaned (a node whose
    parent exited first): reaped here, their CPU seconds count in the run's, not lost with
    init's. Linux only; elsewhere nothing changes."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def reap_orphans() -> None:
    """Reap every child that has exited (orphans adopted included); one still running — a busy
    loop, a process left behind — is left alone (its CPU is not counted)."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def clean_run(load: int, revision: str = "HEAD") -> dict[str, object]:
    """One ``.ci/run`` on a fresh clone of ``revision``, ``load`` busy loops beside it."""
    commit = subprocess.run(["git", "rev-parse", "--short", revision], cwd=REPO, text=True,
                            capture_output=True, check=True).stdout.strip()
    probe = speed_probe()
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        with tempfile.TemporaryDirectory(prefix="twinslam-clean-") as tmp:
            root = Path(tmp)
            (root / "shared").symlink_to(SHARED.resolve())
            subprocess.run(["git", "clone", "-q", str(REPO), str(root / "main")], check=True)
            subprocess.run(["git", "checkout", "-q", commit], cwd=root / "main", check=True)
            started, cpu_before = time.monotonic(), children_cpu_s()
            done = subprocess.run([str(root / "main" / ".ci" / "run")], cwd=root / "main",
                                  text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  env=clone_environment())
            wall = time.monotonic() - started
            reap_orphans()
            cpu = children_cpu_s() - cpu_before
            logs = REPO / "build" / "clean-clone"
            logs.mkdir(parents=True, exist_ok=True)
            stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
            (logs / f"{commit}-{stamp}.log").write_text(done.stdout, encoding="utf-8")
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    return {"date_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M"), "commit": commit,
            "load": load, "rc": done.returncode, "wall_s": round(wall), "cpu_s": round(cpu),
            "probe_s": probe, **_summary(done.stdout.strip())}


def append_row(path: Path, row: dict[str, object]) -> None:
    """One row onto ``path``'s CSV; a file written before a column was added gets it (empty
    in its older rows), so every run of the benchmark stays in one table."""
    rows: list[dict[str, str]] = []
    rewrite = not path.exists()
    if path.exists():
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames != FIELDS:
                rows, rewrite = list(reader), True
    if rewrite:
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=FIELDS, restval="")
            writer.writeheader()
            writer.writerows(rows)
    with path.open("a", newline="", encoding="utf-8") as fh:
        csv.DictWriter(fh, fieldnames=FIELDS).writerow(row)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=1, help="runs, one after another "
                        "(default %(default)s)")
    parser.add_argument("--load", type=int, default=0,
                        help="busy loops beside every run (default %(default)s)")
    parser.add_argument("--baseline", metavar="REV",
                        help="before each run of the revision, one of this revision's clone")
    parser.add_argument("--revision", metavar="REV", default="HEAD",
                        help="the revision measured (default %(default)s, resolved once at the "
                        "start: commits made while the runs go on are not measured)")
    parser.add_argument("--csv", type=Path, help="append one row a run to this CSV")
    args = parser.parse_args()
    if not SHARED.is_dir():
        print(f"note: {SHARED} is missing: the runs play the synthetic room", file=sys.stderr)
    measured = subprocess.run(["git", "rev-parse", args.revision], cwd=REPO, text=True,
                              capture_output=True, check=True).stdout.strip()
    revisions = [args.baseline, measured] if args.baseline else [measured]
    adopt_orphans()
    for k in range(args.runs):
        for revision in revisions:
            print(f"run {k + 1}/{args.runs}: .ci/run on a fresh clone of {revision[:10]}"
                  + (f", {args.load} busy loops beside it" if args.load else ""), flush=True)
            row = clean_run(args.load, revision)
            print(f"  {row['commit']}: rc {row['rc']}, {row['wall_s']} s wall, "
                  f"{row['cpu_s']} s CPU, probe {row['probe_s']} s, pytest "
                  f"{row['pytest_s']} s, {row['passed']} passed, {row['failed']} failed, "
                  f"{row['skipped']} skipped"
                  + (f": {row['failures']}" if row["failures"] else ""), flush=True)
            if args.csv:
                append_row(args.csv, row)


if __name__ == "__main__":
    main()
