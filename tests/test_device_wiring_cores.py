"""The device's frame pairing and camera intake, edge watchdog and upload worker, driven
without DDS and without waiting: injected clocks, a real token-bucket shaper, writes that fail
on purpose."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_msgs.msg import Image

from device_tracker.camera_input import CameraIntake
from device_tracker.edge_watchdog import EdgeWatchdog
from device_tracker.frame_pairing import FramePairing
from device_tracker.uplink_sender import Carried, UplinkSender, write_with_retry
from tests.test_uplink_shaper import VirtualTime
from twinslam.uplink.shaper import UplinkShaper


def _drain(pairing: FramePairing) -> list[tuple[int, str | None, str | None]]:
    return [(f.stamp_key, f.color, f.depth) for f in pairing.ready()]


def test_colour_and_depth_pair_by_stamp_whatever_order_they_come_in() -> None:
    pairing = FramePairing()
    for key in (1, 2, 3):                            # the colour topic runs ahead
        pairing.add("color", key, f"c{key}")
    assert _drain(pairing) == []                     # depth may still come for each
    pairing.add("depth", 1, "d1")
    assert _drain(pairing) == [(1, "c1", "d1")]
    pairing.add("depth", 3, "d3")                    # depth 2 was lost: never coming now
    assert _drain(pairing) == [(2, "c2", None), (3, "c3", "d3")]


def test_a_lone_depth_image_is_handed_out_to_be_dropped() -> None:
    pairing = FramePairing()
    pairing.add("depth", 5, "d5")
    pairing.add("color", 6, "c6")
    frames = list(pairing.ready())
    assert frames[0].color is None and frames[0].newest_color == 6
    with pytest.raises(ValueError, match="image kind"):
        pairing.add("infrared", 7, "i7")


def test_without_a_depth_topic_colour_waits_a_bounded_number_of_frames() -> None:
    pairing = FramePairing(max_pending=2)
    for key in (1, 2):
        pairing.add("color", key, f"c{key}")
    assert _drain(pairing) == []
    pairing.add("color", 3, "c3")
    assert _drain(pairing) == [(1, "c1", None)]      # 3 pending > 2: the oldest goes


def _image(kind: str, stamp_s: int) -> Image:
    """A 2×2 colour (rgb8) or depth (16UC1, 1 m) image of ``stamp_s``."""
    msg = Image(height=2, width=2, encoding="rgb8" if kind == "color" else "16UC1",
                step=6 if kind == "color" else 4)
    msg.data = (np.full(12, stamp_s, np.uint8) if kind == "color"
                else np.full(4, 1000, np.uint16).view(np.uint8)).tobytes()
    msg.header.stamp.sec = stamp_s
    return msg


def test_a_tracker_far_behind_its_camera_drops_its_oldest_waiting_frames_and_says_so() -> None:
    """The node takes images in as they come and tracks on a thread of its own: what waits
    for the tracker is bounded, the oldest frames going first, counted as skipped."""
    intake = CameraIntake(backlog=3)
    for stamp in range(1, 6):
        for kind in ("color", "depth"):
            intake.add(kind, _image(kind, stamp))
    assert intake.waiting == 3 and intake.skipped == 2
    said: list[str] = []
    frames = list(intake.frames(said.append))
    assert [f.stamp for f in frames] == [3.0, 4.0, 5.0]
    assert frames[0].color[0, 0, 0] == 3 and np.allclose(frames[0].depth, 1.0)
    assert len(said) == 1 and "2 oldest waiting frame(s) dropped" in said[0]
    assert list(intake.frames(said.append)) == [] and len(said) == 1      # said once
    intake.add("color", _image("color", 6))
    intake.add("depth", _image("depth", 2))      # the late half of a dropped frame
    assert intake.waiting == 1 and intake.skipped == 2
    with pytest.raises(ValueError, match="at least 1 frame"):
        CameraIntake(backlog=0)


def test_the_watchdog_says_once_that_the_edge_is_silent_and_how_long_it_was() -> None:
    clock = VirtualTime()
    clock.now = 0.0
    dog = EdgeWatchdog(3.0, clock.clock)
    assert dog.check() is None                       # nothing asked yet
    dog.asked(0)
    clock.now = 1.0
    dog.asked(1)
    assert dog.answered(0) is None and dog.check() is None    # answered in time
    clock.now = 4.5
    assert dog.check() == (1, 3.5)
    clock.now = 9.0
    dog.asked(2)
    assert dog.check() is None                       # already said
    clock.now = 10.0
    assert dog.answered(2) == pytest.approx(9.0)     # silent since slot 1 went out at t=1
    assert dog.unanswered == {} and dog.check() is None


def test_a_failing_write_is_retried_until_it_succeeds_or_the_deadline() -> None:
    clock = VirtualTime()
    clock.now = 0.0
    failures = iter([True, True, False])

    def flaky() -> None:
        if next(failures):
            raise RuntimeError("writer blocked")

    assert write_with_retry(flaky, 1.0, clock.clock, clock.sleep) is None
    assert clock.now == pytest.approx(0.2)

    def dead() -> None:
        raise RuntimeError("writer blocked")

    failure = write_with_retry(dead, 1.0, clock.clock, clock.sleep)
    assert isinstance(failure, RuntimeError) and clock.now == pytest.approx(1.3)


def test_the_upload_worker_sends_what_was_asked_at_the_slots_rate_and_reports_it() -> None:
    clock = VirtualTime()
    clock.now = 0.0
    written: list[tuple[float, bytes]] = []
    reports, errors = [], []
    held = {10: b"a" * 100, 11: b"b" * 100}

    def encode(slot: int, frame: int) -> tuple[int, bytes, int] | None:
        return (frame, held[frame], 625_000) if frame in held else None   # 5 Mbit charged

    sender = UplinkSender(UplinkShaper(clock.clock, clock.sleep), encode,
                          lambda b: written.append((clock.now, b)), reports.append, errors.append,
                          default_rate=40.0, clock=clock.clock, sleep=clock.sleep)
    sender.rates[0] = (50.0, 1)
    out = sender.send_slot(0, [10, 11, 12])          # 12 is no longer held
    assert [b[:1] for _, b in written] == [b"a", b"b"]
    assert [t for t, _ in written] == pytest.approx([0.1, 0.2])    # 5 Mbit at 50 Mbit/s
    assert reports == [out] and out.frames_sent == 2 and out.rate_state == 1
    assert out.configured_rate_mbps == 50.0 and errors == []
    out = sender.send_slot(1, [10])                   # no rate drawn: the default
    assert out.configured_rate_mbps == 40.0


def test_an_outage_slot_sends_nothing_and_reports_zero_instead_of_crashing_the_worker() -> None:
    """A trace at its real rate has 0 Mbit/s slots; the shaper refuses a 0 rate, so the worker
    must not start one (a request for frames then is an edge error, logged)."""
    clock = VirtualTime()
    clock.now = 0.0
    written, reports, errors = [], [], []
    sender = UplinkSender(UplinkShaper(clock.clock, clock.sleep), lambda s, f: (f, b"x", 1000),
                          written.append, reports.append, errors.append, default_rate=40.0,
                          clock=clock.clock, sleep=clock.sleep)
    sender.rates[5] = (0.0, 0)
    out = sender.send_slot(5, [])
    assert out.frames_sent == 0 and out.configured_rate_mbps == 0.0 and errors == []
    out = sender.send_slot(5, [50, 51])
    assert written == [] and reports[-1] is out and out.frames_sent == 0
    assert "uplink is down" in errors[0]


def test_a_relocalisation_request_costs_uplink_time_and_is_counted_in_the_next_report() -> None:
    """A lost device's request goes up the keyframes' link: it waits for the keyframes queued
    before it, takes its bytes' time at the rate of the slot that ended last, delays the
    keyframes after it, and the next slot's report counts it apart from the keyframes; in an
    outage it is not sent, and the log says so."""
    clock = VirtualTime()
    clock.now = 0.0
    written: list[tuple[float, bytes]] = []
    reports, errors = [], []
    sender = UplinkSender(UplinkShaper(clock.clock, clock.sleep),
                          lambda s, f: (f, b"k", 625_000), lambda b: written.append((clock.now, b)),
                          reports.append, errors.append, default_rate=40.0, clock=clock.clock,
                          sleep=clock.sleep)
    sender.rates.update({0: (50.0, 1), 1: (0.0, 0)})
    sender.send_slot(0, [10])                                     # 5 Mbit: done at 0.1 s
    request = Carried(0, b"r" * 125_000, lambda b: written.append((clock.now, b)), "request")
    assert sender.send_carried(request)                           # 1 Mbit at 50: 0.02 s
    out = sender.send_slot(0, [11])                               # after it: 0.12 + 0.1 s
    assert [(round(t, 3), b[:1]) for t, b in written] == [(0.1, b"k"), (0.12, b"r"), (0.22, b"k")]
    assert (reports[0].request_bytes, out.request_bytes) == (0, 125_000)
    assert out.bytes_sent == 625_000 and out.frames_sent == 1     # keyframes apart
    assert sender.send_slot(0, []).request_bytes == 0             # counted once
    assert not sender.send_carried(Carried(1, b"r", written.append, "request (frame 7)"))
    assert len(written) == 3 and "uplink is down" in errors[-1] and "frame 7" in errors[-1]


def test_the_worker_thread_sends_a_carried_request_between_slots_in_order() -> None:
    order: list[str] = []
    sender = UplinkSender(UplinkShaper(), lambda s, f: (f, b"x", 10),
                          lambda b: order.append(b.decode()), lambda t: None, lambda m: None,
                          default_rate=1000.0)
    sender.start()
    sender.request(0, [0])
    sender.carry(Carried(0, b"r", lambda b: order.append(b.decode()), "request"))
    sender.request(1, [1])
    sender.close(timeout=10.0)
    assert order == ["x", "r", "x"]


def test_a_keyframe_that_cannot_be_written_is_given_up_and_the_slot_goes_on() -> None:
    clock = VirtualTime()
    clock.now = 0.0
    errors: list[str] = []

    def blocked(payload: bytes) -> None:
        raise RuntimeError("timed out")

    sender = UplinkSender(UplinkShaper(clock.clock, clock.sleep), lambda s, f: (f, b"x", 1000),
                          blocked, lambda t: None, errors.append, default_rate=40.0,
                          retry_s=2.0, clock=clock.clock, sleep=clock.sleep)
    out = sender.send_slot(3, [30, 31])
    assert out.slot == 3 and len(errors) == 2
    assert "keyframe 30 not written within 2 s" in errors[0]


def test_the_worker_thread_sends_requests_in_order_and_stops() -> None:
    done: list[int] = []
    sender = UplinkSender(UplinkShaper(), lambda s, f: (f, b"x", 10), lambda b: None,
                          lambda t: done.append(t.slot), lambda m: None, default_rate=1000.0)
    sender.start()
    for slot in range(3):
        sender.request(slot, [slot])
    sender.close(timeout=10.0)
    assert done == [0, 1, 2]


def test_the_device_path_keeps_only_its_newest_poses() -> None:
    """device/path is a window (path_window poses), not the whole run re-sent every slot."""
    from geometry_msgs.msg import PoseStamped

    from msg_schemas.paths import PathWindow

    window = PathWindow(3)
    for i in range(10):
        pose = PoseStamped()
        pose.pose.position.x = float(i)
        window.add(pose)
    path = window.message(12.5, "map")
    assert [p.pose.position.x for p in path.poses] == [7.0, 8.0, 9.0]
    assert path.header.frame_id == "map" and path.header.stamp.sec == 12
    with pytest.raises(ValueError, match="at least one pose"):
        PathWindow(0)
