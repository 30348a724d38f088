"""The pacing of a player by its device's poses (twinslam.sequence_player.pacing), without
ROS: when the next frame may go out, what a late or missing pose does, the time held, and
the cameras of a group that keep one recording clock."""

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


def test_a_camera_holds_while_another_of_its_group_waits_for_its_device() -> None:
    """Another camera of the group waits for its device: this one, its own device posing
    everything, holds with it — the other's held time growing with the clock while it says it
    waits — and goes on once it has held as long as the other did in all."""
    pacing = DevicePacing(window=5, give_up_s=60.0)
    assert pacing.may_publish(0.0)
    pacing.group_said("/ar2/sequence_player", 0.0, waiting=True, now_s=0.5)
    assert not pacing.may_publish(1.0) and pacing.holding
    assert pacing.told(1.5) == (pytest.approx(0.5), False)   # held for the group, not a device
    assert not pacing.may_publish(2.0)                       # it still waits
    pacing.group_said("/ar2/sequence_player", 2.0, waiting=False, now_s=2.5)
    assert pacing.group_wait_s(2.5) == pytest.approx(0.5)
    assert not pacing.may_publish(2.9)
    assert pacing.may_publish(3.0) and not pacing.holding
    assert pacing.held_s == pytest.approx(2.0)


def test_a_camera_following_its_group_never_holds_beyond_the_groups_time() -> None:
    """Woken late (a timer, a busy process), a camera held for its group alone counts only
    the group's time: two followers each a little late would otherwise push each other on
    without end."""
    pacing = DevicePacing(window=5, give_up_s=60.0)
    pacing.group_said("/ar2/sequence_player", 1.0, waiting=False, now_s=0.0)
    assert not pacing.may_publish(0.0)
    assert pacing.told(1.7) == (pytest.approx(1.0), False)    # not 1.7
    assert pacing.may_publish(1.7)
    assert pacing.held_s == pytest.approx(1.0)
    # another follower a hair later says as much back: nobody holds for it
    pacing.group_said("/ar3/sequence_player", 1.0 + 1e-4, waiting=False, now_s=1.8)
    assert pacing.group_wait_s(1.8) == 0.0 and pacing.may_publish(1.8)


def test_a_hold_for_the_device_counts_in_full_and_says_it_waits() -> None:
    """This camera's device fell behind: the hold is the device's — every second of it the
    recording's clock stopped, whatever the group held (less), and the group is told that it
    waits; a camera gone silent while it waited is taken at its last word (plus at most the
    silence allowed), not waited for without end."""
    pacing = DevicePacing(window=1, give_up_s=60.0, silence_s=5.0)
    pacing.published(0)
    pacing.group_said("/ar2/sequence_player", 0.5, waiting=False, now_s=0.0)
    assert not pacing.may_publish(1.0)
    assert pacing.told(3.0) == (pytest.approx(2.0), True)
    pacing.posed(0, now_s=4.0)
    assert pacing.may_publish(4.0) and pacing.held_s == pytest.approx(3.0)
    assert pacing.told(4.0) == (pytest.approx(3.0), False)
    gone = DevicePacing(window=1, give_up_s=60.0, silence_s=5.0)
    gone.group_said("/ar2/sequence_player", 1.0, waiting=True, now_s=0.0)
    assert gone.group_held_at(100.0) == pytest.approx(6.0)


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


def test_a_pace_report_that_names_no_camera_or_no_duration_is_refused() -> None:
    """What the player's subscription refuses before the pacing sees it: a report a group
    could not follow (a negative held time would make a camera play ahead of its group)."""
    from msg_schemas import new
    from msg_schemas.validation import MessageError, validate

    def report(camera: str, sec: int, nanosec: int) -> object:
        return new("twinslam_msgs/msg/PlaybackPace", camera=camera, waiting_for_device=False,
                   held=new("builtin_interfaces/msg/Duration", sec=sec, nanosec=nanosec))

    validate("twinslam_msgs/msg/PlaybackPace", report("/ar1/sequence_player", 3, 5))
    for camera, sec, nanosec in (("", 1, 0), ("/ar1/sequence_player", -1, 0),
                                 ("/ar1/sequence_player", 0, 1_000_000_000)):
        with pytest.raises(MessageError):
            validate("twinslam_msgs/msg/PlaybackPace", report(camera, sec, nanosec))


def test_a_held_time_crosses_the_report_to_the_nanosecond_and_never_as_a_second_of_them(
        ) -> None:
    """What a camera tells its group (``ros_duration``) is what the group reads back
    (``time_seconds``); a time a hair under a whole second keeps 999 999 999 ns, never 10⁹."""
    from msg_schemas.headers import ros_duration, time_seconds

    for held in (0.0, 0.5, 12.345678901, 86_399.999999):
        assert time_seconds(ros_duration(held)) == pytest.approx(held, abs=1e-9)
    almost = ros_duration(2.9999999999)
    assert (almost.sec, almost.nanosec) == (2, 999_999_999)
