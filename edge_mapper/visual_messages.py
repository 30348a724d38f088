"""What a viewer (RViz, Foxglove) sees of the edge's map: standard messages only, built once a
slot when the slot closes. Pure conversion, no DDS.

* ``edge/map_points`` — ``sensor_msgs/PointCloud2`` of every map point: x, y, z (float32,
  metres, the map frame) and ``intensity`` = how many keyframes observe it;
* ``edge/keyframes`` — ``geometry_msgs/PoseArray`` of the kept keyframes' camera-to-map poses
  (at most V_max);
* ``edge/decisions`` — ``visualization_msgs/MarkerArray`` of what the slot did: one sphere list
  each for the keyframes it integrated (green), evicted (red, where they were), brought back
  from the archive (blue) and kept (grey), in namespaces ``integrated``, ``evicted``,
  ``restored``, ``kept``; a namespace with nothing this slot is sent with ``DELETE`` so the
  viewer clears last slot's;
* ``edge/keyframe_trajectory`` — ``nav_msgs/Path`` of every keyframe the edge keeps, the map's
  and the archive's, oldest first, each ``PoseStamped`` stamped with the keyframe's capture
  time and posed where the edge holds it now: ORB-SLAM's keyframe trajectory, the one place a
  loop's correction of archived keyframes shows (a map update carries only the map's).

Frame id ``map`` (the edge's map frame, the frame of ``edge/map_update`` and ``device/pose``),
stamps the slot's close (the stamp of the slot's ``edge/map_update``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from geometry_msgs.msg import Point, PoseArray, PoseStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from msg_schemas.headers import ros_time, set_header
from msg_schemas.interfaces import new
from msg_schemas.poses import pose_msgs
from twinslam.slam.back_end.keyframe_map import KeyFrameMap

#: x, y, z, intensity as float32: 16 bytes a point
POINT_FIELDS = tuple(PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                     for i, name in enumerate(("x", "y", "z", "intensity")))
#: sphere diameter of a keyframe marker, metres
KEYFRAME_MARKER_M = 0.06
#: colour of each decision, RGBA
DECISION_COLOURS = {"integrated": (0.1, 0.8, 0.2, 1.0), "evicted": (0.9, 0.1, 0.1, 1.0),
                    "restored": (0.1, 0.4, 0.95, 1.0), "kept": (0.6, 0.6, 0.6, 0.8)}


def map_points_message(keyframe_map: KeyFrameMap, stamp: float, frame_id: str = "map"
                       ) -> PointCloud2:
    """Every map point as one unorganised cloud (height 1, width = the map's point count)."""
    rows = keyframe_map.columns.ids_and_rows()[1]      # the points' own order
    data = np.zeros((len(rows), 4), dtype=np.float32)
    data[:, :3] = keyframe_map.columns.positions[rows]
    data[:, 3] = keyframe_map.columns.observed[rows]
    cloud = new(PointCloud2, height=1, width=len(rows), fields=list(POINT_FIELDS),
                is_bigendian=False, point_step=16, row_step=16 * len(rows), is_dense=True,
                data=data.view(np.uint8).reshape(-1))        # the float32 rows' bytes, once
    return set_header(cloud, stamp, frame_id)


def keyframes_message(keyframe_map: KeyFrameMap, stamp: float, frame_id: str = "map"
                      ) -> PoseArray:
    """The kept keyframes' poses, oldest id first."""
    poses = PoseArray(poses=pose_msgs([keyframe_map.keyframes[k].pose
                                       for k in sorted(keyframe_map.keyframes)]))
    return set_header(poses, stamp, frame_id)


def keyframe_trajectory_message(trajectory: Sequence[tuple[float, np.ndarray]], stamp: float,
                                frame_id: str = "map") -> Path:
    """(capture time s, camera-to-map pose) pairs as one path stamped ``stamp``."""
    poses = [set_header(PoseStamped(pose=pose), taken, frame_id)
             for (taken, _), pose in zip(trajectory, pose_msgs([p for _, p in trajectory]),
                                         strict=True)]
    return set_header(Path(poses=poses), stamp, frame_id)


def decisions_message(keyframe_map: KeyFrameMap, integrated: list[int], evicted: list[int],
                      poses_before: Mapping[int, np.ndarray], stamp: float,
                      frame_id: str = "map", restored: Sequence[int] = ()) -> MarkerArray:
    """The slot's integrated, evicted, restored and kept keyframes as four sphere lists;
    ``poses_before`` holds where the evicted ones were (they are gone from the map)."""
    new = set(integrated) | set(restored)
    kept = [k for k in sorted(keyframe_map.keyframes) if k not in new]
    in_map = keyframe_map.keyframes
    where = {"integrated": [in_map[k].pose for k in integrated if k in in_map],
             "evicted": [poses_before[k] for k in evicted if k in poses_before],
             "restored": [in_map[k].pose for k in restored if k in in_map],
             "kept": [in_map[k].pose for k in kept]}
    return MarkerArray(markers=[_spheres(ns, poses, stamp, frame_id)
                                for ns, poses in where.items()])


def _spheres(namespace: str, poses: list[np.ndarray], stamp: float, frame_id: str) -> Marker:
    marker = Marker(ns=namespace, id=0, type=Marker.SPHERE_LIST,
                    action=Marker.ADD if poses else Marker.DELETE)
    marker.header.stamp = ros_time(stamp)
    marker.header.frame_id = frame_id
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = KEYFRAME_MARKER_M
    marker.color = ColorRGBA(r=DECISION_COLOURS[namespace][0], g=DECISION_COLOURS[namespace][1],
                             b=DECISION_COLOURS[namespace][2], a=DECISION_COLOURS[namespace][3])
    marker.points = [Point(x=float(p[0, 3]), y=float(p[1, 3]), z=float(p[2, 3])) for p in poses]
    return marker
