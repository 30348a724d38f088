"""A background thread's name where the operating system shows it, not only in Python.

Python names its threads for itself (``threading.Thread(name=...)``): Linux, ``top -H``,
``ps -L``, ``htop`` and ``/proc/PID/task/TID/comm`` show every thread an interpreter started
under the process's own name, so on an edge that is CPU-bound one cannot tell the slot thread
from the loop closer's worker, the keyframe database's word learning or the checkpoint writer
— the question a user of a loaded edge asks first ("which thread takes the cores?"), and the
one ``bench.process_cpu --threads`` answers by these names. On Linux a thread may rename
itself: its name is written to its own ``comm`` file, at most OS_NAME_BYTES bytes. Elsewhere,
or where the file cannot be written (a sandbox), the thread keeps the name it had.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

#: what Linux keeps of a thread's name (16 bytes with the terminating zero)
OS_NAME_BYTES = 15


def name_this_thread(name: str | None = None) -> str | None:
    """Give the calling thread ``name`` (None: its Python name) where the operating system
    shows it; the name it shows now, cut to OS_NAME_BYTES bytes, or None where threads have
    no name of their own there or the name could not be set."""
    if not sys.platform.startswith("linux"):
        return None
    encoded = (name or threading.current_thread().name).encode("utf-8", "replace")
    wanted = encoded[:OS_NAME_BYTES].decode("utf-8", "ignore")
    comm = Path(f"/proc/self/task/{threading.get_native_id()}/comm")
    try:
        comm.write_text(wanted)
        return comm.read_text().rstrip("\n")
    except OSError:
        return None
