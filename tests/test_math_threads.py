"""A node's math libraries run on one thread unless the user sized their pools."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

#: what a node process does first (run_node), then what its libraries' pools are
PROBE = """
import json, os
import numpy, scipy.linalg, faiss, gtsam
from threadpoolctl import threadpool_info
from twinslam.node_runtime.math_threads import one_math_thread
limited = one_math_thread()
print(json.dumps({"limited": limited, "pools": [p["num_threads"] for p in threadpool_info()],
                  "openblas": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _probe(**env: str) -> dict:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env}, check=True,
                         capture_output=True, text=True, timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: every pool is one thread")
def test_a_node_runs_every_blas_and_openmp_pool_on_one_thread() -> None:
    """The edge's four OpenBLAS copies and faiss' OpenMP start a thread a core; a node limits
    them all (their spinning took half the edge's CPU), and its children start with one."""
    seen = _probe()
    assert seen["limited"] is True
    assert len(seen["pools"]) >= 2 and set(seen["pools"]) == {1}
    assert seen["openblas"] == "1"


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: every pool is one thread")
def test_a_pool_size_the_user_set_is_kept() -> None:
    seen = _probe(OMP_NUM_THREADS="2")
    assert seen["limited"] is False
    assert 2 in seen["pools"]
