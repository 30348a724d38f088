"""Live runs whose camera waits for its device, and the check that the device kept up.

A device slower than its camera falls behind and, past its camera backlog, drops frames: on a
loaded machine (CI's may be half as fast as a developer's) a live test then measures the load,
not what it checks — a dropped frame loses a slot of the device's frame-count clock, a track,
a merge's timing. The live tests play with the player's ``pace_frames`` at PACE_FRAMES (the
player holds its next frame while that many are unposed) and fail where the device said it
fell behind all the same (docs/testing.md).
"""

from __future__ import annotations

from device_tracker.camera_input import FELL_BEHIND

#: the camera waits for its device beyond this many unposed frames: a slot of the tests'
#: 30-frame slots (unpaced, CI's device fell its 150-frame queue behind in the link-down test,
#: dropped 66 frames and lost a slot)
PACE_FRAMES = 30


def assert_kept_up(device_log: str, device: str = "the device") -> None:
    """The device never said it dropped frames it could not keep up with."""
    assert FELL_BEHIND not in device_log, f"{device} fell behind its camera: {device_log[-2000:]}"
