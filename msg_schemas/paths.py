"""A recent trajectory as ``nav_msgs/Path``: a bounded window, not the whole run.

A viewer needs the recent motion; a whole run's path grows without bound (a 60-minute run at
30 Hz is 108 000 poses, re-sent each time) while the per-frame pose topics already carry every
pose. So ``device/path`` and ``camera/ground_truth_path`` hold the newest ``path_window`` poses
(a parameter of the device and the player: 900, i.e. 30 s at 30 Hz, by default), the same
window on both so that they compare in a viewer. Pure conversion, no DDS.
"""

from __future__ import annotations

from collections import deque

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path

from msg_schemas.headers import set_header


class PathWindow:
    """The newest ``window`` poses, oldest first."""

    def __init__(self, window: int) -> None:
        if window < 1:
            raise ValueError(f"the path window must hold at least one pose, got {window}")
        self.poses: deque[PoseStamped] = deque(maxlen=window)

    def add(self, pose: PoseStamped) -> None:
        self.poses.append(pose)

    def message(self, stamp: float, frame_id: str) -> Path:
        """The window as ``nav_msgs/Path``, stamped ``stamp`` in ``frame_id``."""
        path: Path = set_header(Path(poses=list(self.poses)), stamp, frame_id)
        return path
