"""The edge's viewer topics are made only for a viewer that listens: nothing is built while
nobody subscribes, a viewer that joins gets the map at the next slot's end, and a trajectory
that fell due while nobody listened is sent to it then."""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from edge_mapper.viewer_topics import ViewerTopics
from msg_schemas import qos, topics
from msg_schemas.headers import stamp_key
from twinslam.node_runtime.session import RosSession
from twinslam.slam.back_end.keyframe_map import KeyFrameMap


def _map_with_points(n: int) -> KeyFrameMap:
    m = KeyFrameMap()
    m.add_keyframe(1, np.eye(4))
    for i in range(n):
        pid = m.add_point(np.array([0.1 * i, 0.0, 2.0]), np.zeros(32, dtype=np.uint8))
        m.observe(1, pid, (100.0 + i, 200.0), 2.0)
    return m


def test_viewer_topics_are_made_for_a_viewer_that_listens_and_the_trajectory_is_owed_to_it(
        ros: RosSession) -> None:
    views = ViewerTopics(ros.node, lambda topic: f"ar1/{topic}", trajectory_every=30)
    asked: list[int] = []

    def trajectory() -> list[tuple[float, np.ndarray]]:
        asked.append(1)
        return [(0.5, np.eye(4))]

    def finish(m: KeyFrameMap, slot: int) -> None:
        views.publish(m, slot, float(slot), "ar1/map", [1], [], [], {}, False, trajectory)

    finish(_map_with_points(3), 0)        # the trajectory is due at slot 0: nobody listens
    assert views.skipped == 4 and not asked and views.trajectory_owed

    got: dict[str, list[Any]] = {"cloud": [], "poses": [], "marks": [], "path": []}
    for key, kind, topic in (("cloud", PointCloud2, topics.MAP_POINTS),
                             ("poses", PoseArray, topics.KEYFRAME_POSES),
                             ("marks", MarkerArray, topics.DECISIONS),
                             ("path", Path, topics.KEYFRAME_TRAJECTORY)):
        ros.node.create_subscription(kind, f"ar1/{topic}", got[key].append, qos.MAP)
    assert ros.spin_until(lambda: all(p.get_subscription_count() > 0
                                      for p in views.publishers), 30.0)
    finish(_map_with_points(5), 1)        # not a trajectory slot, but one is owed
    assert ros.spin_until(lambda: all(got.values()), 30.0), {k: len(v) for k, v in got.items()}
    assert got["cloud"][-1].width == 5 and stamp_key(got["cloud"][-1].header) == 1_000_000_000
    assert len(got["poses"][-1].poses) == 1 and len(got["path"][-1].poses) == 1
    assert views.skipped == 4 and len(asked) == 1 and not views.trajectory_owed

    finish(_map_with_points(6), 2)        # the cloud again; no trajectory due or owed
    assert ros.spin_until(lambda: len(got["cloud"]) == 2, 30.0)
    assert got["cloud"][-1].width == 6 and len(asked) == 1
