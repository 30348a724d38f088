"""Every thread's native (C/C++) stack of a running process, read with ``gdb`` where the host has
it: what a Python stack cannot show when a node is stuck inside a C extension — rclpy's teardown,
a DDS call — with the interpreter's lock held. A node that did not end once when signalled (a
clean clone, 2026-12-02) showed only ``destroy_node`` as its Python stack; the next such hang
shows where below it the process waits."""

from __future__ import annotations

import shutil
import subprocess

#: how long gdb may take to attach, walk every thread and detach
GDB_TIMEOUT_S = 60.0


def native_stacks(pid: int, timeout_s: float = GDB_TIMEOUT_S) -> str | None:
    """``thread apply all bt`` of process ``pid`` (its frames and thread headers only), or None
    where there is no gdb, it may not attach (ptrace) or it did not finish in ``timeout_s``."""
    gdb = shutil.which("gdb")
    if gdb is None:
        return None
    try:
        done = subprocess.run([gdb, "-p", str(pid), "-batch", "-nx", "-ex", "thread apply all bt"],
                              capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired):
        return None
    lines = [line for line in done.stdout.splitlines()
             if line.startswith(("#", "Thread "))]
    return "\n".join(lines) or None
