"""Where and how twinslam's node processes run, around rclpy (which is the client library).

* :mod:`twinslam.node_hosts.node_main` — the life of a one-node process (init, spin, clean teardown,
  exit code 2 with the reason when a node cannot start);
* :mod:`twinslam.node_hosts.parameters` — parameters declared with descriptors, ranges and live
  checks;
* :mod:`twinslam.node_hosts.checked_subscription` — subscriptions that validate content first;
* :mod:`twinslam.node_hosts.matched_readers` — a writer that logs when its readers match;
* :mod:`twinslam.node_hosts.fastdds` — the DDS environment: domain, discovery range, Fast DDS
  profile;
* :mod:`twinslam.node_hosts.loopback` — a private domain on this machine and the processes in it;
* :mod:`twinslam.node_hosts.netns` — device, edge and twin as network-namespace hosts with a cable
  each,
  and :mod:`twinslam.node_hosts.ebpf_loss`, random packet loss where ``tc netem`` is missing.
"""
