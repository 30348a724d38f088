"""A node started by a test, a benchmark or a launcher ends with the process that started it.

:class:`~twinslam.hosts.loopback.ProcessDomain` stops its node processes when it closes. A
starter killed outright (SIGKILL, a test runner stopped twice with Ctrl-C, a CI job cut at its
timeout) closes nothing: its nodes ran on, in a domain id whose claim the kernel gave back
with the starter's death, and the next test to claim that id found them talking on its topics
— an orphan twin node answered a later test's edge once on this machine (2026-12-04).

The starter names itself in :data:`PARENT_ENV` (its pid); a node that finds it there asks the
kernel for SIGTERM when that process dies (``PR_SET_PDEATHSIG``) — the stop every node already
takes, bounded — and stops at once where the starter died before the request was made (the
node is then another process's child). A node started by hand, or by ``ros2 launch``, has no
such variable and is left alone. The fork server's children die with their server already
(:mod:`twinslam.hosts.forked`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
from collections.abc import MutableMapping

#: the environment variable naming the process a node ends with (its pid)
PARENT_ENV = "TWINSLAM_STOP_WITH_PARENT"
PR_SET_PDEATHSIG = 1            #: prctl option (linux/prctl.h)


def stop_with_parent(env: MutableMapping[str, str] = os.environ) -> bool:
    """Have the kernel send this process SIGTERM when the process :data:`PARENT_ENV` names
    dies; True when it is no longer this process's parent (it died already, or this process
    was not started by it): the caller stops. False, and nothing asked, without the variable
    or where the kernel offers no ``prctl`` (not Linux). The variable leaves ``env``: what
    this process starts is not its starter's."""
    named = env.pop(PARENT_ENV, "")
    if not named.isdigit():
        return False
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    ctypes.CDLL(libc_name, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    # asked after the fork: a parent that died in between sent nothing; its child was
    # given to another process meanwhile
    return os.getppid() != int(named)
