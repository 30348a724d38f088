"""A fork server for the fork server's own tests (``python -m tests.nodes.fork_probe FD``): its
one module, ``probe``, prints what its process was given and exits with the code it is asked
for, or waits to be signalled."""

from __future__ import annotations

import json
import os
import sys
import time

from twinslam.hosts.forked import run_server

PRELOADED = os.getpid()        #: the server's pid, as the children see it (a preloaded value)


def probe(_args: list[str] | None) -> int:
    """``probe exit CODE`` or ``probe wait``: one JSON line on stdout, one line on stderr."""
    print(json.dumps({"argv": sys.argv, "cwd": os.getcwd(), "pid": os.getpid(),
                      "ppid": os.getppid(), "preloaded_by": PRELOADED,
                      "ros": os.environ.get("ROS_DOMAIN_ID"),
                      "marker": os.environ.get("PROBE_MARKER"),
                      "test": os.environ.get("PYTEST_CURRENT_TEST"),
                      "netns": os.readlink("/proc/thread-self/ns/net")}))
    print("probe on stderr", file=sys.stderr)
    if sys.argv[1] == "wait":
        time.sleep(60)
    return int(sys.argv[2])


if __name__ == "__main__":
    sys.exit(run_server(sys.argv, {"probe": probe}))
