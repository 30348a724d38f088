"""sequence_player node entry point (the player itself lands with the front-end issue #4)."""

from __future__ import annotations

import sys

from node_runtime.idle_node import run_idle_node

PARAMETERS = {"sequence": "synthetic", "rate": 1.0, "loop": False, "start": 0, "end": -1}


def main(args: list[str] | None = None) -> int:
    return run_idle_node("sequence_player", PARAMETERS,
                         "sequence replay is not implemented yet (issue #4)", args)


if __name__ == "__main__":
    sys.exit(main())
