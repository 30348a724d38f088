"""udt_node: the user digital twin's ROS 2 node (the twin itself is :mod:`twinslam.twin`)."""
