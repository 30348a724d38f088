"""REP 105 for a device tracked against an edge's map: ``map → odom → camera``.

The device's pose in ``map`` jumps whenever the map under it is corrected — a map update from
the edge (bundle adjustment moved its keyframes, restores brought others back), a
relocalisation, the first frame tracked again after a loss. Content a user anchors in ``map``
stays at its place in the world through those jumps, but it moves on screen at once. REP 105
(and robot_localization, Nav2, rtabmap, the ORB-SLAM3 ROS wrappers) splits the pose in two:

* ``odom → camera`` is continuous: the device's own motion from frame to frame, integrated.
  Across a correction the motion is the one of the frames before (constant velocity), never
  the jump; content anchored in ``odom`` never leaps, it drifts slowly instead;
* ``map → odom`` takes every correction: ``map → camera`` = ``map → odom`` · ``odom → camera``
  holds at every frame, so the ``map`` pose is exactly the tracker's.

A frame is a correction when it was tracked against another map version than the frame
before, relocalised, or is the first tracked after untracked frames (their poses are the motion
model's guesses, and the tracked pose after them says where the guesses went wrong).
"""

from __future__ import annotations

import numpy as np


def _orthonormal(pose: np.ndarray) -> np.ndarray:
    """``pose`` with its rotation projected back onto SO(3): a product of thousands of frame
    steps drifts off it in floating point."""
    u, _, vt = np.linalg.svd(pose[:3, :3])
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        u[:, -1] = -u[:, -1]
        rotation = u @ vt
    out = pose.copy()
    out[:3, :3] = rotation
    return out


class OdometryFrame:
    """The device's ``odom`` frame, frame by frame (no ROS: the node publishes what
    :meth:`update` returns)."""

    def __init__(self) -> None:
        self._map_pose: np.ndarray | None = None      #: the last frame's camera-to-map pose
        self._odom: np.ndarray | None = None          #: the last frame's camera-to-odom pose
        self._step = np.eye(4)                        #: the last motion that was no correction
        self._version = 0
        self._tracked = False
        self.corrections = 0                          #: frames whose map pose was corrected

    def update(self, map_pose: np.ndarray, tracked: bool, map_version: int,
               relocalised: bool) -> tuple[np.ndarray, np.ndarray]:
        """(camera-to-odom, odom-to-map) of a frame whose camera-to-map pose is ``map_pose``.
        The first frame starts ``odom`` where ``map`` is."""
        pose = np.asarray(map_pose, dtype=np.float64)
        if self._odom is None or self._map_pose is None:
            self._odom = pose.copy()
        else:
            corrected = tracked and (relocalised or map_version != self._version
                                     or not self._tracked)
            if corrected:
                self.corrections += 1
                step = self._step
            else:
                step = np.linalg.inv(self._map_pose) @ pose
                self._step = step
            self._odom = _orthonormal(self._odom @ step)
        self._map_pose, self._version, self._tracked = pose, map_version, tracked
        return self._odom.copy(), pose @ np.linalg.inv(self._odom)
