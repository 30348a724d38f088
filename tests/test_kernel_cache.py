"""The numba kernel cache shared by several processes (``twinslam.kernel_cache``): a process
saving a new overload of a kernel waits while another one saves, so no overload's entry is
lost and none points at another overload's machine code. Measured without the lock: of five
rounds of eight processes compiling eight overloads of one kernel at once, one lost an entry
and its float64 overload then ran the int64 code (3.5 → 7.0 where 2·3.5 + 1 = 8.0)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from bench.kernel_cache_race import kernel_env, read_index

KERNEL = textwrap.dedent("""
    from twinslam.kernel_cache import njit


    @njit(cache=True)
    def twice_plus_one(x):
        return x * 2 + 1
""")
#: the overloads the processes compile, one each (argv[1] picks it)
VALUES = ("np.int64(3)", "np.float64(3.5)", "np.float32(1.5)", "np.int32(2)")
RUN = "import numpy as np, kernel; print(float(kernel.twice_plus_one({value})))"


def _run(folder: Path, value: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", RUN.format(value=value)], cwd=folder,
                            env=kernel_env(folder), stdout=subprocess.PIPE, text=True)


def _waiting_on(path: Path) -> bool:
    """Whether a process waits for a lock on ``path`` (``/proc/locks``: a waiter's line has
    ``->``, the file as MAJOR:MINOR:INODE)."""
    inode = f":{os.stat(path).st_ino} "
    return any("->" in line and inode in line for line in Path("/proc/locks").read_text()
               .splitlines())


@pytest.mark.skipif(not Path("/proc/locks").exists(), reason="needs Linux's /proc/locks")
def test_a_second_overload_is_saved_only_after_the_first_process_let_go(tmp_path: Path) -> None:
    import fcntl

    (tmp_path / "kernel.py").write_text(KERNEL, encoding="utf-8")
    first = _run(tmp_path, VALUES[0])
    assert first.communicate(timeout=120)[0].strip() == "7.0"
    index, overloads = read_index(tmp_path)
    assert len(overloads) == 1
    lock_path = Path(f"{index}.lock")
    with lock_path.open("a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)                 # another process saving
        second = _run(tmp_path, VALUES[1])
        deadline = time.monotonic() + 120
        while not _waiting_on(lock_path) and second.poll() is None and \
                time.monotonic() < deadline:
            time.sleep(0.05)
        assert _waiting_on(lock_path), "the second process did not wait for the lock"
        assert len(read_index(tmp_path)[1]) == 1             # nothing saved meanwhile
    assert second.communicate(timeout=120)[0].strip() == "8.0"
    _, overloads = read_index(tmp_path)
    assert len(overloads) == len(set(overloads.values())) == 2


def test_processes_compiling_overloads_at_once_keep_each_ones_code(tmp_path: Path) -> None:
    """Four processes, four overloads, at once: the index keeps four entries in four files, and
    a fresh process loads each overload from them and gets its own answer."""
    (tmp_path / "kernel.py").write_text(KERNEL, encoding="utf-8")
    procs = [_run(tmp_path, value) for value in VALUES]
    assert [p.communicate(timeout=120)[0].strip() for p in procs] == ["7.0", "8.0", "4.0", "5.0"]
    _, overloads = read_index(tmp_path)
    assert len(overloads) == len(set(overloads.values())) == len(VALUES)
    check = ("import numpy as np, kernel\n"
             f"print([float(kernel.twice_plus_one(v)) for v in ({', '.join(VALUES)})],"
             " len(kernel.twice_plus_one.stats.cache_hits))")
    done = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, env=kernel_env(tmp_path),
                          capture_output=True, text=True, timeout=120)
    assert done.stdout.split("]")[0] + "]" == "[7.0, 8.0, 4.0, 5.0]", done.stderr
    assert done.stdout.split("]")[1].strip() == str(len(VALUES))   # all loaded, none compiled
