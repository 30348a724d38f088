"""A bound on the middleware's teardown: a node process whose DDS participant's deletion does
not end within :data:`TEARDOWN_S` prints where it is stuck and exits (code 1), instead of
waiting for ``ros2 launch`` (or a test) to kill it.

Why a bound, not a fix: the deletion can deadlock inside Fast DDS 2.14.5 as the ROS 2 wheels on
PyPI build it. The last node's ``destroy_node`` deletes the process's participant, and
rmw_fastrtps first calls the participant's ``set_listener(nullptr)`` with no timeout. That call
takes the participant's listener lock and waits for every discovery callback then running to
finish, with a steady-clock deadline of ``time_point::max()``. The wheel's libstdc++ has no
``pthread_cond_clockwait`` (libfastrtps imports only ``pthread_cond_timedwait``): it converts
the deadline to the system clock, where it overflows, and each wait returns at once without
waiting — the thread spins in ``steady_clock::now`` with the lock held.
A discovery callback that was running when it began (a peer leaving at that moment: a launch
stops every node at once) needs the lock to finish, and never gets it. A twin node stuck in
``destroy_node`` failed the test suite twice (2026-12-02 and 2026-12-04, no native frames
kept); a stress made for it (the twin beside a process of eight readers, stopped together)
hung it twice in 619 stops, both times with the main thread in
``DomainParticipant::set_listener`` under ``rmw_fastrtps_shared_cpp::destroy_participant`` and a
receive thread in ``PDP::remove_remote_participant`` → ``onParticipantDiscovery`` waiting for a
mutex. Every thread of the stuck process put on one CPU from outside (``taskset -a``) did not
free it in 10 s: the spinning thread does not release the lock between its turns. Bounded,
the twin ended twice in 508 stops of that stress at the bound, code 1, and 0 every other time.

Nothing the node owns is left to do by then (its ``close`` ran), but the participant's
departure was not announced: its peers drop it when its lease ends. The bound is
:func:`faulthandler.dump_traceback_later`, a thread of the interpreter's C runtime that needs no
interpreter lock — the stuck main thread holds it.
"""

from __future__ import annotations

import faulthandler
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: the longest a node's destruction (its DDS participant deleted) may take: it takes well
#: under a second; ``ros2 launch`` sends SIGKILL 10 s after its SIGINT, and a node's own
#: ``close`` comes first
TEARDOWN_S = 5.0
#: what the bound prints first when it ends a process (faulthandler's own line)
TIMEOUT_MARK = "Timeout ("


@contextmanager
def teardown_bound(seconds: float = TEARDOWN_S) -> Iterator[None]:
    """Within the block, a process still there after ``seconds`` prints every thread's Python
    stack to stderr (after :data:`TIMEOUT_MARK`) and exits with code 1."""
    faulthandler.dump_traceback_later(seconds, exit=True, file=sys.stderr)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def stuck_in_teardown(log: str) -> bool:
    """Whether a node's log ends with the bound's report of a destruction that did not end:
    its mark, then a stack in ``destroy_node`` (the deadlock above, not the node's own code)."""
    at = log.rfind(TIMEOUT_MARK)
    return at >= 0 and "in destroy_node" in log[at:]


def ended_as_asked(code: int, log: str) -> bool:
    """Whether a node that was asked to end (or ended its own run: a player done playing)
    ended as it should: code 0, or code 1 at the bound of a destruction stuck in the
    middleware (:func:`stuck_in_teardown`), its own work done before."""
    return code == 0 or (code == 1 and stuck_in_teardown(log))
