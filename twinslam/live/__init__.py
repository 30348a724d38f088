"""Live runs: the nodes as processes on a domain, a monitor node, the report of a run, sweeps of
runs (scenario x map source x policy x seed) and their tables, the simulator's view of the
played frames. What ``twinslam launch``, ``evaluate`` and ``demo`` drive, and what bench.live
measures."""
