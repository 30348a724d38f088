"""What runs inside a node process, around rclpy (which is the client library).

* :mod:`twinslam.node_runtime.node_main` — the life of a one-node process (init, spin, clean
  teardown, exit code 2 with the reason when a node cannot start), with
  :mod:`twinslam.node_runtime.allocator` keeping freed memory in the process and
  :mod:`twinslam.node_runtime.middleware_teardown` bounding the DDS participant's deletion
  (it can deadlock in Fast DDS);
* :mod:`twinslam.node_runtime.parameters` — parameters declared with descriptors, ranges and
  live checks;
* :mod:`twinslam.node_runtime.checked_subscription` — subscriptions that validate content first;
* :mod:`twinslam.node_runtime.matched_readers` — a writer that logs when its readers match (a
  reader when its writers do), and
  :mod:`twinslam.node_runtime.acks`, waiting for reliable readers to acknowledge;
* :mod:`twinslam.node_runtime.session` — an rclpy node with its own context and executor inside
  a process that does other work (monitors, tests), stopped cleanly by
  :mod:`twinslam.node_runtime.interrupts`.

Where those processes run — a private domain, network-namespace hosts, forked processes, the
DDS environment — is :mod:`twinslam.hosts`; the two never import each other.
"""
