"""Compile the numba kernels of the device, the edge (its policies and its twin allocator), the
synthetic worlds and the depth registration of a sequence whose cameras differ once, at set-up.

The kernels are compiled on first use and cached beside their sources (``cache=True``). On a
fresh checkout that first use is the first node start: the edge took 58 s to reach "listening
on" on a 2-core machine instead of 4 s, with nothing on the console meanwhile, and a test or a
launcher that waits a minute for a node could give up on a healthy one. ``make`` runs this
module after installing, so the first start is as fast as every later one; a kernel whose
source changed afterwards is recompiled at its next use (numba checks the source's stamp).

    python -m twinslam.cli.precompile
"""

from __future__ import annotations

import sys
import time

from twinslam.live.node_fork_server import load_kernels


def main() -> int:
    start = time.monotonic()
    print("compiling the device, edge and synthetic-world kernels (once after a change; "
          "about a minute on 2 cores)", flush=True)
    load_kernels()
    print(f"kernels ready in {time.monotonic() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
