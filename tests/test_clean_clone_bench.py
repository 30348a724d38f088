"""bench.clean_clone's bookkeeping: the CPU seconds of a run count the processes it left
orphaned, and its CSV keeps every earlier run when a column is added."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

from bench.clean_clone import FIELDS, append_row

#: a grandchild that burns 0.5 s of CPU after its parent exited (an orphan)
BURN = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.5: pass"


def test_the_cpu_of_a_process_orphaned_by_the_run_is_counted() -> None:
    """A run whose process left a child behind (it exited first): the child's 0.5 s of CPU
    count in the run's. In a process of its own: a reaper of orphans is for a benchmark's
    process, not a test worker's."""
    orphaning = ("import subprocess, sys; "
                 f"subprocess.Popen([sys.executable, '-c', {BURN!r}]); sys.exit(0)")
    measure = "\n".join([
        "import subprocess, sys, time",
        "import bench.clean_clone as c",
        "c.adopt_orphans()",
        "before = c.children_cpu_s()",
        f"subprocess.run([sys.executable, '-c', {orphaning!r}], check=True)",
        "deadline = time.monotonic() + 30",
        "while c.children_cpu_s() - before < 0.5 and time.monotonic() < deadline:",
        "    c.reap_orphans()",
        "    time.sleep(0.05)",
        "print(c.children_cpu_s() - before)"])
    done = subprocess.run([sys.executable, "-c", measure], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr
    assert float(done.stdout) >= 0.5, "the orphan's CPU seconds were lost"


def test_a_column_added_keeps_the_earlier_runs_in_one_table(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    old = ["date_utc", "commit", "load", "rc", "wall_s", "pytest_s", "passed", "failed",
           "skipped", "failures"]
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=old)
        writer.writeheader()
        writer.writerow({k: "1" for k in old})
    row = {k: "2" for k in FIELDS}
    append_row(path, row)
    append_row(path, row)
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
    assert reader.fieldnames == FIELDS and len(rows) == 3
    assert rows[0]["commit"] == "1" and rows[0]["cpu_s"] == ""
    assert rows[1] == rows[2] == row
