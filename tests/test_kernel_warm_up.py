"""The kernels a node loads before its first slot are the ones its slots run.

``make`` compiles the numba kernels once (``twinslam.cli.precompile``) and every node loads
them before it listens (``load_kernels``); a kernel called in a slot with arguments of
another type or memory layout compiles a second overload there, seconds on a fresh checkout,
and that slot's map update is late. A short shared walk in process must add no overload to
any kernel: two devices on the corridor, the second 70 frames behind, its map merged into the
first's at its third slot and lent the first's keyframes (the kernels a 300-frame walk used
are the same six: the synthetic world's, the front end's, the merge's join and the slot
scores).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: load the kernels as a node does, walk, and print every overload the walk added
_WALK = """
import runpy, sys
from numba.core.registry import CPUDispatcher
from twinslam.live.node_fork_server import load_kernels

OURS = ("twinslam", "edge_mapper", "device_tracker", "udt_node")

def overloads():
    found = {}
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] in OURS:
            for value in list(vars(module).values()):
                if isinstance(value, CPUDispatcher):
                    key = f"{value.__module__}.{value.__name__}"
                    found[key] = {str(s) for s in value.signatures}
    return found

load_kernels()
before = overloads()
sys.argv = ["place_walks", "--devices", "2", "--frames", "200", "--after", "70"]
runpy.run_module("bench.place_walks", run_name="__main__")
for kernel, signatures in sorted(overloads().items()):
    for signature in sorted(signatures - before.get(kernel, set())):
        print(f"COMPILED IN A SLOT: {kernel}{signature}")
"""


def test_a_shared_walk_compiles_no_kernel_the_nodes_did_not_load_before_it() -> None:
    run = subprocess.run([sys.executable, "-c", _WALK], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "cross-device revisit error" in run.stdout, run.stdout[-2000:]
    compiled = [line for line in run.stdout.splitlines()
                if line.startswith("COMPILED IN A SLOT")]
    assert not compiled, "\n".join(compiled)
