"""Every thread's native (C/C++) stack of a running process, read with ``gdb`` where the host has
it: what a Python stack cannot show when a node is stuck inside a C extension — rclpy's teardown,
a DDS call — with the interpreter's lock held. A node that did not end once when signalled (a
clean clone, 2026-12-02) showed only ``destroy_node`` as its Python stack; the next such hang
shows where below it the process waits. The report puts the main thread first and keeps it
short: the next hang (CI, 2026-12-04) printed all thirteen threads in gdb's order, the main
thread last, and the CI log kept only the start and the end of it — the main thread's frames
that said where it waited were the part cut out."""

from __future__ import annotations

import re
import shutil
import subprocess

#: how long gdb may take to attach, walk every thread and detach
GDB_TIMEOUT_S = 60.0


def native_stacks(pid: int, timeout_s: float = GDB_TIMEOUT_S) -> str | None:
    """Every thread's native stack of process ``pid`` (``thread apply all bt``, as
    :func:`compact_stacks` shortens it), or None where there is no gdb, it may not attach
    (ptrace) or it did not finish in ``timeout_s``."""
    gdb = shutil.which("gdb")
    if gdb is None:
        return None
    try:
        done = subprocess.run([gdb, "-p", str(pid), "-batch", "-nx", "-ex", "thread apply all bt"],
                              capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return compact_stacks(done.stdout)


#: frames of the interpreter and of a thread's start: the same in every Python process, and
#: the Python stack (faulthandler) already says where in Python each thread is
_PLUMBING = re.compile(r" in (_?Py\w*|pymain_\w*|Py_\w*|__libc_start\w*|_start|clone3|"
                       r"start_thread|method_vectorcall\w*|cfunction\w*|_PyEval\w*)[ (]")

#: a frame line's length kept: C++ frames name every template argument and parameter type, and
#: a hang's report must fit the part of a CI log that is kept (its start and its end)
FRAME_CHARS = 180


def compact_stacks(gdb_output: str) -> str | None:
    """gdb's ``thread apply all bt`` as a hang's report needs it: the main thread (gdb's
    Thread 1, listed last) first — where the process waits, which a truncated log must not
    lose — each frame without its address and cut to :data:`FRAME_CHARS`, the interpreter's
    own frames left out (counted). None when the output holds no thread."""
    threads: list[list[str]] = []
    for line in gdb_output.splitlines():
        if line.startswith("Thread "):
            threads.append([line[:FRAME_CHARS]])
        elif line.startswith("#") and threads:
            threads[-1].append(line)
    if not threads:
        return None
    main = [t for t in threads if t[0].startswith("Thread 1 ")]
    ordered = main + [t for t in threads if t not in main]
    out: list[str] = []
    for header, *frames in ordered:
        out.append(header)
        skipped = 0
        for frame in frames:
            if _PLUMBING.search(frame):
                skipped += 1
                continue
            out.append(re.sub(r"^(#\d+)\s+0x[0-9a-f]+ in ", r"\1 ", frame)[:FRAME_CHARS])
        if skipped:
            out.append(f"   ({skipped} frames of the interpreter or a thread's start left out)")
    return "\n".join(out)
