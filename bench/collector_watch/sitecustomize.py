"""Times every garbage collection of the process it is imported into, for
``bench.edge_scaling --collector-log``: on the ``PYTHONPATH`` of the edge processes the bench
starts, Python imports it at start-up (the ``sitecustomize`` hook), and each collection of
generation 1 or 2, or any longer than 2 ms, is appended to ``$TWINSLAM_COLLECTOR_LOG/PID.txt``
as ``unix-time generation milliseconds collected``. Nothing happens without that variable.
"""

from __future__ import annotations

import gc
import os
import time
from typing import Any

_FOLDER = os.environ.get("TWINSLAM_COLLECTOR_LOG")
if _FOLDER:
    _log = open(os.path.join(_FOLDER, f"{os.getpid()}.txt"), "a", buffering=1)
    _started: list[float] = []

    def _timed(phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            _started[:] = [time.perf_counter()]
            return
        ms = (time.perf_counter() - (_started[0] if _started else time.perf_counter())) * 1e3
        if info["generation"] >= 1 or ms > 2.0:
            _log.write(f"{time.time():.3f} {info['generation']} {ms:.2f} "
                       f"{info.get('collected', 0)}\n")

    gc.callbacks.append(_timed)
