"""A background thread shows its name where Linux shows threads (``top -H``, ``ps -L``,
``/proc``): a loaded edge's loop closer, word learning and checkpoint writer are told apart
from its slot thread there, not all under the process's name."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest

from twinslam.thread_names import OS_NAME_BYTES, name_this_thread

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="threads have no name of their own here")


def _os_name(tid: int) -> str:
    return Path(f"/proc/self/task/{tid}/comm").read_text().rstrip("\n")


def _in_thread(python_name: str, name: str | None = None) -> tuple[str | None, str]:
    """What ``name_this_thread`` returned in a thread named ``python_name``, and the name
    Linux shows for that thread afterwards (while it still runs)."""
    seen: dict[str, object] = {}
    done, read = threading.Event(), threading.Event()

    def run() -> None:
        seen["returned"] = name_this_thread(name)
        seen["tid"] = threading.get_native_id()
        done.set()
        read.wait(5.0)

    thread = threading.Thread(target=run, name=python_name)
    thread.start()
    assert done.wait(5.0)
    tid = seen["tid"]
    assert isinstance(tid, int)
    shown = _os_name(tid)
    read.set()
    thread.join(5.0)
    returned = seen["returned"]
    assert returned is None or isinstance(returned, str)
    return returned, shown


def test_a_thread_shows_its_python_name_and_leaves_the_callers() -> None:
    mine = _os_name(threading.get_native_id())
    assert _in_thread("place-words") == ("place-words", "place-words")
    assert _os_name(threading.get_native_id()) == mine


def test_a_long_name_is_cut_to_what_linux_keeps_and_a_name_given_wins() -> None:
    returned, shown = _in_thread("checkpoint-writer-of-the-edge")
    assert returned == shown == "checkpoint-writer-of-the-edge"[:OS_NAME_BYTES]
    assert _in_thread("Thread-7", "loop-closer_0") == ("loop-closer_0", "loop-closer_0")
