"""The edge's messages survive CDR: map updates, keyframes, upload requests, map stats."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from device_tracker.messages import (
    FrameRecord,
    frame_summaries_message,
    keyframe_message,
    read_map_update,
)
from edge_mapper.messages import (
    map_stats_message,
    map_update_message,
    read_frame_summaries,
    read_keyframe,
    upload_request_message,
)
from msg_schemas import new, type_name_of
from msg_schemas.poses import pose_matrix, pose_msg
from msg_schemas.validation import MessageError, validate
from twinslam.policies.actions import MapAction
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.keyframe import TRACK_ID_BIT, KeyFramePayload
from twinslam.uncertainty.map_uncertainty import SlotUncertainty


def _roundtrip(msg: object) -> object:
    out = deserialize_message(serialize_message(msg), type(msg))
    validate(type_name_of(msg), out)
    return out


def _pose(angle: float, t: list[float]) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    p = np.eye(4)
    p[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    p[:3, 3] = t
    return p


def test_pose_conversion_round_trips() -> None:
    p = _pose(0.7, [1.0, -2.0, 0.5])
    np.testing.assert_allclose(pose_matrix(_roundtrip(pose_msg(p))), p, atol=1e-12)


def test_map_update_round_trip() -> None:
    rng = np.random.default_rng(0)
    m = KeyFrameMap()
    for k in (5, 9):
        m.add_keyframe(k, _pose(0.1 * k, [k, 0, 0]))
    for _ in range(4):
        pid = m.add_point(rng.normal(size=3), rng.integers(0, 256, 32, dtype=np.uint8))
        m.observe(5, pid)
        if pid % 2:
            m.observe(9, pid)
    local = read_map_update(_roundtrip(map_update_message(m, slot=3, version=7, stamp=12.5)))
    assert local.version == 7 and local.keyframe_ids.tolist() == [5, 9]
    np.testing.assert_allclose(local.keyframe_poses[1], m.keyframes[9].pose, atol=1e-12)
    assert local.point_ids.tolist() == sorted(m.points)
    np.testing.assert_array_equal(local.positions, [m.points[p].position for p in sorted(m.points)])
    np.testing.assert_array_equal(local.descriptors[2], m.points[3].descriptor)
    assert local.observations.tolist() == [2, 1, 2, 1]


def test_a_map_update_carries_the_loops_frame_correction_and_a_bad_one_is_refused() -> None:
    """The loops' composed correction crosses to the device exactly (identity when none was
    closed); one that is no rigid motion (a NaN, a quaternion that is not a unit) is refused
    by name before a device would move its points by it."""
    m = KeyFrameMap()
    m.add_keyframe(5, _pose(0.2, [1.0, 0.0, 0.0]))
    assert np.array_equal(read_map_update(_roundtrip(map_update_message(
        m, slot=3, version=7, stamp=1.0))).frame_correction, np.eye(4))
    correction = _pose(0.05, [0.1, -0.02, 0.03])
    msg = _roundtrip(map_update_message(m, slot=3, version=7, stamp=1.0,
                                        frame_correction=correction))
    validate("twinslam_msgs/msg/MapUpdate", msg)
    np.testing.assert_allclose(read_map_update(msg).frame_correction, correction, atol=1e-12)
    for field, value in (("x", math.nan), ("w", 3.0)):
        bad = _roundtrip(msg)
        setattr(bad.frame_correction.orientation, field, value)
        with pytest.raises(MessageError, match=r"frame_correction\.orientation"):
            validate("twinslam_msgs/msg/MapUpdate", bad)


def test_keyframe_reading_keeps_ids_and_track_bits() -> None:
    msg = new("twinslam_msgs/msg/Keyframe", slot=4, frame_id=123,
              pose_estimate=pose_msg(_pose(0.2, [0, 1, 0])),
              k=np.array([500.0, 0, 320, 0, 500, 240, 0, 0, 1]),
              keypoints_xy=np.array([10, 20, 30, 40], dtype=np.float32),
              keypoint_depths=np.array([1.5, 0.0], dtype=np.float32),
              descriptors=np.arange(64, dtype=np.uint8),
              map_point_ids=np.array([17, int(TRACK_ID_BIT) | 3], dtype=np.uint64))
    kf = read_keyframe(_roundtrip(msg))
    assert (kf.frame_id, kf.slot) == (123, 4)
    np.testing.assert_array_equal(kf.keypoints, [[10, 20], [30, 40]])
    assert kf.point_ids.tolist() == [17, (1 << 63) | 3]
    assert kf.descriptors.shape == (2, 32) and kf.descriptors[1, 0] == 32
    np.testing.assert_allclose(kf.pose, _pose(0.2, [0, 1, 0]), atol=1e-12)


def test_upload_request_and_map_stats() -> None:
    req = _roundtrip(upload_request_message(2, "adapt", 60.0, MapAction([31, 40], [3]), 1.0))
    assert req.upload_frame_ids.tolist() == [31, 40] and req.evict_frame_ids.tolist() == [3]
    stats = _roundtrip(map_stats_message(2, "lff", KeyFrameMap(), math.inf, None, 2,
                                         12.0, 30.0, 1.0, frame_id="ar1/map"))
    assert stats.header.frame_id == "ar1/map"              # whose map the counts describe
    assert math.isinf(stats.uncertainty) and math.isnan(stats.mean_uncertainty)
    assert math.isnan(stats.tracked_uncertainty)
    assert stats.lost_share == 0.0 and stats.map_size == 0
    # one of four frames lost: it scores 0 in the mean, the tracked mean leaves it out
    upsilon = SlotUncertainty(tracked_sum=-300.0, n_tracked=3, n_frames=4, map_uncertainty=-90)
    stats = _roundtrip(map_stats_message(3, "lff", KeyFrameMap(), -90.0, upsilon, 2, 12.0,
                                         30.0, 1.0))
    assert stats.mean_uncertainty == -75.0 and stats.tracked_uncertainty == -100.0
    assert stats.lost_share == 0.25


def test_device_messages_round_trip_into_the_edge_readers() -> None:
    from device_tracker.messages import FrameRecord, frame_summaries_message

    rec = FrameRecord(41, 12.25, _pose(0.3, [1, 2, 3]), True, np.array([5, 9], np.uint64),
                      np.array([int(TRACK_ID_BIT) | 2], np.uint64), 7, relocalised=True)
    msg = _roundtrip(frame_summaries_message(7, 60.0, 1, 3, [rec], 12.5))
    f = msg.frames[0]
    assert (msg.slot, msg.map_version, f.frame_id, f.stamp.sec, f.stamp.nanosec) == \
        (7, 3, 41, 12, 250_000_000)
    assert f.map_point_ids.tolist() == [5, 9] and f.local_track_ids.tolist() == [(1 << 63) | 2]
    assert f.tracked and f.relocalised
    np.testing.assert_allclose(pose_matrix(f.pose), rec.pose, atol=1e-12)
    (seen,) = read_frame_summaries(msg)
    assert (seen.frame_id, seen.map_points, seen.tracks, seen.tracked, seen.map_version) == \
        (41, frozenset({5, 9}), frozenset({(1 << 63) | 2}), True, 0)
    assert all(type(i) is int for i in seen.map_points | seen.tracks)
    np.testing.assert_allclose(seen.pose, rec.pose, atol=1e-12)
    sent = KeyFramePayload(41, 7, 12.25, rec.pose, np.diag([500.0, 500.0, 1.0]),
                           np.array([[1.0, 2.0]]), np.array([2.5]), np.full((1, 32), 7, np.uint8),
                           np.array([9], np.uint64))
    kf = read_keyframe(_roundtrip(keyframe_message(sent)))
    assert kf.frame_id == 41 and kf.point_ids.tolist() == [9] and kf.depths.tolist() == [2.5]
    assert kf.stamp == 12.25 and kf.slot == 7
    np.testing.assert_allclose(kf.intrinsics, sent.intrinsics)


def test_a_summary_carries_each_frames_cpu_time_and_a_bad_one_is_refused() -> None:
    """The device reports its tracking thread's CPU milliseconds a frame (what the live
    tables show as device CPU); a negative or non-finite figure is refused by name."""
    record = FrameRecord(7, 1.5, np.eye(4), True, np.array([3], np.uint64),
                         np.zeros(0, np.uint64), 0, cpu_ms=12.5)
    msg = _roundtrip(frame_summaries_message(0, 40.0, 0, 1, [record], 1.6))
    assert msg.frames[0].cpu_ms == 12.5
    validate("twinslam_msgs/msg/FrameSummaries", msg)
    for bad in (-1.0, math.nan):
        msg.frames[0].cpu_ms = bad
        try:
            validate("twinslam_msgs/msg/FrameSummaries", msg)
        except MessageError as exc:
            assert "frames[7].cpu_ms" in str(exc)
        else:
            raise AssertionError(f"cpu_ms {bad} accepted")


def test_map_stats_count_the_keyframes_restored_from_the_archive() -> None:
    stats = _roundtrip(map_stats_message(4, "lff", KeyFrameMap(), -90.0, None, 1, 1.0, 2.0,
                                         1.0, archived=7, restored=2))
    assert (stats.archived_keyframes, stats.restored_keyframes) == (7, 2)


def test_decision_markers_tell_integrated_evicted_restored_and_kept_keyframes_apart() -> None:
    """What a viewer draws of one slot: the uploads integrated, the keyframes evicted (where
    they were), those brought back from the archive and the rest of the map, each its own
    namespace and colour; a namespace with nothing this slot clears the viewer's last."""
    from visualization_msgs.msg import Marker

    from edge_mapper.visual_messages import decisions_message

    m = KeyFrameMap()
    for kf in (2, 3, 5, 8):
        m.add_keyframe(kf, _pose(0.0, [float(kf), 0.0, 1.0]))
    before = {9: _pose(0.0, [9.0, 0.0, 1.0])}
    marks = {mk.ns: mk for mk in decisions_message(m, [8], [9], before, 1.0, "map",
                                                   restored=[3]).markers}
    xs = {ns: [p.x for p in mk.points] for ns, mk in marks.items()}
    assert xs == {"integrated": [8.0], "evicted": [9.0], "restored": [3.0], "kept": [2.0, 5.0]}
    colours = {(mk.color.r, mk.color.g, mk.color.b) for mk in marks.values()}
    assert len(colours) == 4 and all(mk.action == Marker.ADD for mk in marks.values())
    quiet = {mk.ns: mk.action for mk in decisions_message(m, [8], [], {}, 2.0).markers}
    assert quiet["restored"] == quiet["evicted"] == Marker.DELETE


def test_the_keyframe_trajectory_is_a_path_of_keyframes_at_their_capture_times() -> None:
    """edge/keyframe_trajectory as a viewer and the run's report read it: one PoseStamped a
    keyframe, stamped when its frame was captured (what pairs it with the frame's summary),
    the path stamped when the slot closed, everything in the map frame."""
    from edge_mapper.visual_messages import keyframe_trajectory_message
    from msg_schemas.headers import stamp_key, time_key
    from msg_schemas.poses import pose_matrix

    poses = [_pose(0.3, [1.0, 2.0, 3.0]), _pose(-0.2, [0.5, 0.0, 1.0])]
    path = _roundtrip(keyframe_trajectory_message([(12.5, poses[0]), (13.25, poses[1])],
                                                  20.0, "ar1/map"))
    assert stamp_key(path.header) == 20 * 10**9 and path.header.frame_id == "ar1/map"
    assert [time_key(p.header.stamp) for p in path.poses] == [12_500_000_000, 13_250_000_000]
    assert {p.header.frame_id for p in path.poses} == {"ar1/map"}
    for sent, got in zip(poses, path.poses, strict=True):
        np.testing.assert_allclose(pose_matrix(got.pose), sent, atol=1e-12)
