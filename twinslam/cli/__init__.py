"""The ``twinslam`` command: offline tools (simulator, graph inspection, the demo)."""
