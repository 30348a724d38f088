"""A small ROS 2 client runtime over Eclipse Cyclone DDS, shaped like rclpy.

rclpy is not installable on the machines twinslam targets without ROS, so the nodes speak DDS
directly with ROS 2's wire conventions (DESIGN.md §6): ``rt/`` topics, ``pkg::msg::dds_::T_``
types, XCDR1, RIHS01 type hashes in USER_DATA, ``enclave=/;``, ``ros_discovery_info``. A node
written against this API looks like an rclpy node::

    node_runtime.init()
    node = MyNode()            # a node_runtime.Node subclass
    node_runtime.run(node)     # spin until SIGINT/SIGTERM, then destroy and shut down
"""

from node_runtime.context import get_context, init, ok, shutdown
from node_runtime.executor import (
    SingleThreadedExecutor,
    fail,
    run,
    spin,
    spin_once,
    start_node,
)
from node_runtime.node import Node, Publisher, Subscription, Timer
from node_runtime.parameters import Parameter, ParameterError
from node_runtime.qos import (
    DEFAULT,
    LATCHED,
    PROTOCOL,
    SENSOR_DATA,
    Durability,
    QoSProfile,
    Reliability,
)

__all__ = [
    "DEFAULT",
    "LATCHED",
    "PROTOCOL",
    "SENSOR_DATA",
    "Durability",
    "Node",
    "Parameter",
    "ParameterError",
    "Publisher",
    "QoSProfile",
    "Reliability",
    "SingleThreadedExecutor",
    "Subscription",
    "Timer",
    "fail",
    "get_context",
    "init",
    "ok",
    "run",
    "shutdown",
    "spin",
    "spin_once",
    "start_node",
]
