"""device_tracker node entry point (tracking and uploads land with the pipeline issue #5)."""

from __future__ import annotations

import sys

from node_runtime.idle_node import run_idle_node

PARAMETERS = {"slot_frames": 60, "alpha_mbit": 5.0, "d_req_s": 0.5, "channel": "markov:N=2"}


def main(args: list[str] | None = None) -> int:
    return run_idle_node("device_tracker", PARAMETERS,
                         "device tracking is not implemented yet (issue #5)", args)


if __name__ == "__main__":
    sys.exit(main())
