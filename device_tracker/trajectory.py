"""The device's recent trajectory as ``device/path``: a bounded window, not the whole run.

A viewer needs the device's recent motion; the whole run's path grows without bound (a
60-minute run at 30 Hz is 108 000 poses, re-sent every slot) and ``device/pose`` already
carries every pose. So the path holds the newest ``path_window`` poses (a parameter: 900, i.e.
30 s at 30 Hz, by default), and is published once per slot. Pure logic, no DDS.
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
