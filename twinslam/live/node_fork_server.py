"""The fork server of the launchers' nodes (:mod:`twinslam.hosts.forked`): the player,
the device and the edge imported and their kernels loaded once, each node then forked from
here in a fraction of the ~1.5 s of CPU it takes to start from nothing.

The twin's node is not preloaded: it loads torch, whose thread pools do not survive a fork.

    python -m twinslam.live.node_fork_server FD      (started by ForkServers, never by hand)
"""

from __future__ import annotations

import sys
from pathlib import Path

from twinslam.hosts.forked import ForkServers, run_server

#: the node modules a fork server preloads (as the launchers run them: ``python -m``)
PRELOADED = frozenset({"twinslam.sequence_player.node", "device_tracker.node",
                       "edge_mapper.node"})
#: ``TWINSLAM_FORK_SERVER=0`` starts every node with ``python -m`` instead
SWITCH = "TWINSLAM_FORK_SERVER"


def load_kernels() -> None:
    """Load (in a fresh checkout: compile) the numba kernels of the device, the edge with each
    rule policy, the synthetic worlds, the depth registration of a sequence whose cameras
    differ, the twin allocator's value curve and integration's look for alike points."""
    import numpy as np

    from device_tracker.device_core import DeviceTrackerCore
    from edge_mapper.edge_core import EdgeMapperCore
    from twinslam.allocation.budget_value import budget_value
    from twinslam.policies.registry import make_policy
    from twinslam.policies.rules import POLICIES
    from twinslam.sequences.registration import register_depth
    from twinslam.sequences.synthetic import SyntheticSequence
    from twinslam.slam.back_end.join_candidates import join_candidates

    DeviceTrackerCore.warm_up()
    for name in POLICIES:
        EdgeMapperCore.warm_up(make_policy(name))
    next(iter(SyntheticSequence(n_frames=1)))
    for depth_to_colour in (None, np.eye(4)):            # both cameras at one place or not
        register_depth(np.ones((2, 2), dtype=np.float32), np.eye(3), np.eye(3),
                       depth_to_colour)
    points = np.arange(40)
    budget_value([points], [points], 0.0, 1, 2)
    one = np.zeros((1, 3))
    join_candidates(one, np.ones(1), np.zeros((1, 32), np.uint8), one,
                    np.zeros((1, 32), np.uint8), np.zeros(1, np.int64), 50)


def fork_servers(cwd: Path) -> ForkServers:
    """The fork servers of this process's launchers (started on first use)."""
    global _SERVERS
    if _SERVERS is None:
        _SERVERS = ForkServers(__name__, PRELOADED, cwd)
    return _SERVERS


_SERVERS: ForkServers | None = None


def main(argv: list[str]) -> int:
    import device_tracker.node
    import edge_mapper.node
    import twinslam.sequence_player.node

    mains = {"twinslam.sequence_player.node": twinslam.sequence_player.node.main,
             "device_tracker.node": device_tracker.node.main,
             "edge_mapper.node": edge_mapper.node.main}
    assert set(mains) == PRELOADED
    return run_server(argv, mains, load_kernels)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
