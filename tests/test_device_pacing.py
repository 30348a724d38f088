"""The pacing of a player by its device's poses (twinslam.sequence_player.pacing), without
ROS: when the next frame may go out, what a late or missing pose does, and the time held."""

from __future__ import annotations

import pytest

from twinslam.sequence_player.pacing import DevicePacing


def test_the_camera_holds_at_the_window_and_goes_on_as_frames_are_posed() -> None:
    pacing = DevicePacing(window=2, give_up_s=60.0)
    for stamp in (0, 100):
        assert pacing.may_publish(stamp * 1e-3)
        pacing.published(stamp)
    assert (pacing.may_publish(0.2), pacing.holding) == (False, True)
    pacing.posed(0, now_s=0.5)                # one posed: one more may go
    assert (pacing.may_publish(0.5), pacing.holding) == (True, False)
    assert pacing.held_s == pytest.approx(0.3)


def test_a_pose_counts_every_frame_before_it_one_the_device_skipped_too() -> None:
    pacing = DevicePacing(window=3, give_up_s=60.0)
    for stamp in (0, 100, 200):
        pacing.published(stamp)
    pacing.posed(200, now_s=1.0)              # frames 0 and 100 never posed
    assert pacing.unposed == 0 and pacing.may_publish(1.0)


def test_a_device_that_never_poses_holds_the_camera_only_until_the_give_up() -> None:
    pacing = DevicePacing(window=1, give_up_s=10.0)
    pacing.published(0)
    assert not pacing.may_publish(1.0)
    assert not pacing.may_publish(11.0)       # 10 s held, not yet more
    assert pacing.may_publish(11.5) and pacing.gave_up and not pacing.active
    pacing.published(100)
    assert pacing.may_publish(11.6)           # real time from then on
    assert pacing.held_s == pytest.approx(10.5)


def test_progress_restarts_the_give_up_clock() -> None:
    pacing = DevicePacing(window=1, give_up_s=10.0)
    pacing.published(0)
    pacing.published(100)                     # two out, window one: held
    assert not pacing.may_publish(1.0)
    pacing.posed(0, now_s=9.0)                # a slow device, but a moving one
    assert not pacing.may_publish(15.0) and not pacing.gave_up


def test_no_window_plays_in_real_time_and_a_negative_one_is_refused() -> None:
    pacing = DevicePacing(window=0, give_up_s=1.0)
    for stamp in range(500):
        pacing.published(stamp)
        assert pacing.may_publish(float(stamp))
    assert pacing.unposed == 0 and pacing.held_s == 0.0
    with pytest.raises(ValueError, match="pacing window"):
        DevicePacing(window=-1, give_up_s=1.0)


def test_the_pace_option_takes_windows_below_the_devices_camera_backlog() -> None:
    """``--pace`` (launch, evaluate): a window at the device's camera backlog would let the
    device drop frames before the camera waits: refused, as a count that is not one."""
    import argparse

    from msg_schemas import qos
    from twinslam.cli.arguments import pace_frames

    backlog = qos.CAMERA.depth
    assert pace_frames("0") == 0 and pace_frames(str(backlog - 1)) == backlog - 1
    for bad in (str(backlog), "-1", "thirty"):
        with pytest.raises(argparse.ArgumentTypeError):
            pace_frames(bad)
