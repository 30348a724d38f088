"""Compile the numba kernels of the device, the edge (its policies and its twin allocator) and
the synthetic room once, at set-up.

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

import numpy as np

from device_tracker.device_core import DeviceTrackerCore
from edge_mapper.edge_core import EdgeMapperCore
from twinslam.map_management.budget_value import budget_value
from twinslam.map_management.policies import POLICIES
from twinslam.policy_registry import make_policy
from twinslam.sequences.synthetic import SyntheticSequence


def main() -> int:
    start = time.monotonic()
    print("compiling the device, edge and synthetic-room kernels (once after a change; "
          "about a minute on 2 cores)", flush=True)
    DeviceTrackerCore.warm_up()
    for name in POLICIES:
        EdgeMapperCore.warm_up(make_policy(name))
    next(iter(SyntheticSequence(n_frames=1)))
    points = np.arange(40)                  # the twin allocator's value curve (issue #32)
    budget_value([points], [points], 0.0, 1, 2)
    print(f"kernels ready in {time.monotonic() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
