"""One thread for the math libraries' own thread pools in a node process, unless asked for more.

numpy, scipy, GTSAM and faiss each bring an OpenBLAS (four copies in one edge process) and
faiss an OpenMP runtime; each starts a pool of one thread a core and hands it every matrix
product or search above a small size. Between calls the pool's threads spin, waiting for the
next. A node is one of several processes sharing the host's cores, and its work is many small
products (poses, a keyframe's points), so the spinning is CPU taken from the other nodes and
the node's other threads rather than speed: measured side by side with ``bench.edge_scaling
--pools cores,one`` on the 2-core machine, the edge serving 4 devices used 94 % of a core
with the pools and 50 % with one thread each, and the share of late maps at 8 devices fell
from 22 % to 14 % (BENCHMARKS.md); live (``bench.live``) the edge's slot took 80 ms instead
of 108 and the device's CPU a frame did not change.

The standard environment variables still decide where a user sets them (``OMP_NUM_THREADS``,
``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS``): a host that runs one node alone may want the
pools back.
"""

from __future__ import annotations

import os

#: the variables through which a user chooses the pools' sizes themselves
USER_CHOICE = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def one_math_thread() -> bool:
    """Limit every BLAS and OpenMP pool loaded in this process to one thread, and set the
    variables so that the libraries loaded later (and child processes) start with one; False
    (nothing changed) where the user set one of :data:`USER_CHOICE`."""
    if any(name in os.environ for name in USER_CHOICE):
        return False
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[name] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    return True
