"""``make run``: the most complete real thing that exists today.

1. Starts the four nodes as separate processes on a private loopback DDS domain, waits until
   each announces itself on ``ros_discovery_info`` and prints the graph, then stops them with
   SIGTERM and checks they exit cleanly.
2. Runs the offline simulator with LFF, PU, ADAPT and the clairvoyant oracle on the
   covisibility the ORB front end extracted from 1000 real 7-Scenes frames (shipped in
   ``data/``; the geometric room model only if that file is missing, and then said so).

The live pipeline (issue #5) replaces step 1's idle nodes.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from node_runtime.loopback import LoopbackDomain

REAL_COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"

NODES = ["sequence_player", "device_tracker", "edge_mapper", "udt_node"]


def run_graph() -> bool:
    import node_runtime
    from node_runtime.context import get_context
    from node_runtime.graph import GraphMonitor

    with LoopbackDomain() as dom:
        dom.activate()
        print(f"[1/2] starting {', '.join(NODES)} on loopback DDS domain {dom.domain_id}",
              flush=True)
        procs = {name: dom.spawn(["-m", f"{name}.node"]) for name in NODES}
        node_runtime.init(args=["demo"], install_signal_handlers=False)
        monitor = GraphMonitor(get_context().participant)
        ok = monitor.wait_for({f"/{n}" for n in NODES}, timeout=60)
        for node in monitor.nodes():
            print(f"      {node.fully_qualified_name:<18} publishers {len(node.writer_gids)} "
                  f"subscriptions {len(node.reader_gids)}")
        node_runtime.shutdown()
        codes = {name: dom.stop(p)[0] for name, p in procs.items()}
        print(f"      stopped with SIGTERM, exit codes {codes}", flush=True)
        return ok and all(c == 0 for c in codes.values())


def run_demo(args: argparse.Namespace) -> int:
    start = time.monotonic()
    graph_ok = run_graph()
    if REAL_COVIS.is_file():
        covis, what = str(REAL_COVIS), ("real covisibility: ORB map points of 1000 7-Scenes "
                                        "frames (data/)")
    else:
        covis, what = "geometric:600", f"the geometric room model ({REAL_COVIS} is missing)"
    print(f"\n[2/2] offline simulator, {args.slots} slots x {args.seeds} seeds — {what}",
          flush=True)
    from twinslam_cli.main import main

    code = main(["sim", "--policy", "lff,pu,adapt,oracle", "--covis", covis,
                 "--slots", str(args.slots), "--seeds", str(args.seeds)])
    print(f"\ndemo finished in {time.monotonic() - start:.0f} s")
    return 0 if graph_ok and code == 0 else 1
