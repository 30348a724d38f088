"""The edge's per-device lines written through rcutils directly: what a user reads on
``/rosout`` (``ros2 topic echo /rosout``, rqt_console, Foxglove's log panel) is the record
rclpy's own logger writes, named by the code that wrote the line, and a level set on the
node's logger still holds."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

from rcl_interfaces.msg import Log
from rclpy.logging import LoggingSeverity
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession
from twinslam.node_runtime.site_logging import SiteLogger

#: /rosout as rclpy's nodes offer it (reliable, transient local)
ROSOUT_QOS = QoSProfile(depth=1000, reliability=QoSReliabilityPolicy.RELIABLE,
                        durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)


def _records(listener: RosSession) -> list[Log]:
    seen: list[Log] = []
    listener.node.create_subscription(Log, "/rosout", seen.append, ROSOUT_QOS)
    return seen


def _arrived(seen: list[Log], text: str) -> Callable[[], bool]:
    return lambda: any(r.msg == text for r in seen)


def _written_by_a_wrapper(lines: SiteLogger, text: str) -> int:
    """As ``DeviceLink.info`` does: the wrapper's caller names the line. Returns the line
    this function called the wrapper from."""
    def wrapper(message: str) -> None:
        lines.info(message)
    wrapper(text)
    return sys._getframe().f_lineno - 1                  # the line above


def test_a_line_reaches_rosout_as_rclpys_own_does_named_by_the_code_that_wrote_it(
        domain: LoopbackDomain) -> None:
    with RosSession("site_writer") as writer, RosSession("site_reader") as reader:
        seen = _records(reader)
        logger = writer.node.get_logger()
        logger.info("through rclpy")
        at = _written_by_a_wrapper(SiteLogger(logger, depth=2), "through rcutils")
        SiteLogger(logger).warning("a warning, at its caller")
        assert reader.spin_until(_arrived(seen, "a warning, at its caller"), 30.0), \
            "no record of the site logger's lines reached /rosout"
        writer.spin_once(0.0)
        by_text = {r.msg: r for r in seen if r.name == logger.name}
        rclpys, ours = by_text["through rclpy"], by_text["through rcutils"]
        assert (ours.level, ours.name) == (rclpys.level, rclpys.name) == (Log.INFO, logger.name)
        assert ours.file == rclpys.file == os.path.abspath(__file__)
        assert (ours.function, ours.line) == ("_written_by_a_wrapper", at)
        warning = by_text["a warning, at its caller"]
        assert warning.level == Log.WARN
        assert warning.function == \
            "test_a_line_reaches_rosout_as_rclpys_own_does_named_by_the_code_that_wrote_it"


def test_a_line_below_the_loggers_level_is_not_written(domain: LoopbackDomain) -> None:
    with RosSession("site_quiet") as writer, RosSession("site_listener") as reader:
        seen = _records(reader)
        logger = writer.node.get_logger()
        logger.set_level(LoggingSeverity.WARN)
        lines = SiteLogger(logger)
        lines.info("under the level")
        lines.error("over the level")
        assert reader.spin_until(_arrived(seen, "over the level"), 30.0), \
            "the error did not reach /rosout"
        # one writer's records arrive in order: the info line would have come first
        assert [r.msg for r in seen if r.name == logger.name] == ["over the level"]
        assert seen[-1].level == Log.ERROR
