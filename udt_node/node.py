"""udt_node entry point (the digital twin lands with issue #6)."""

from __future__ import annotations

import sys

from node_runtime.idle_node import run_idle_node

PARAMETERS = {"states": 2, "latent_dim": 8, "retrain_every": 100, "weights": ""}


def main(args: list[str] | None = None) -> int:
    return run_idle_node("udt_node", PARAMETERS,
                         "the user digital twin is not implemented yet (issue #6)", args)


if __name__ == "__main__":
    sys.exit(main())
