"""Where twinslam's node processes run: the hosts a launch, a test or a benchmark sets up.

* :mod:`twinslam.hosts.fastdds` — the DDS environment: domain, discovery range, Fast DDS
  profile;
* :mod:`twinslam.hosts.loopback` — a private domain on this machine and the processes in it,
  started from :mod:`twinslam.hosts.forked`'s preloaded fork servers;
* :mod:`twinslam.hosts.netns` — device, edge and twin as network-namespace hosts with a cable
  each, and :mod:`twinslam.hosts.ebpf_loss`, random packet loss where ``tc netem`` is missing.

What runs inside a node process (its life, parameters, checked subscriptions) is
:mod:`twinslam.node_runtime`; the two never import each other.
"""
