"""edge_mapper node entry point (the live edge map lands with the pipeline issue #5)."""

from __future__ import annotations

import sys

from node_runtime.idle_node import run_idle_node

PARAMETERS = {"policy": "adapt", "vmax": 45, "alpha_mbit": 5.0, "d_req_s": 0.5,
              "checkpoint": ""}


def main(args: list[str] | None = None) -> int:
    return run_idle_node("edge_mapper", PARAMETERS,
                         "edge mapping is not implemented yet (issue #5)", args)


if __name__ == "__main__":
    sys.exit(main())
