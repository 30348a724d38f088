"""A lost device's requests for relocalisation at the edge: when it sends them (the first lost
frame at once, then one every ``reloc_period_s`` of stamps, none while tracked or on
probation, none at all with 0) and what they carry (the lost frame's features, no image,
as the edge reads them back; a request without features is refused)."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from twinslam_msgs.msg import RelocalisationRequest

from device_tracker.relocalisation_requests import (
    RelocalisationPacer,
    relocalisation_request_message,
)
from msg_schemas.validation import MessageError, validate
from twinslam.slam.keyframe import KeyFramePayload


def test_the_first_lost_frame_goes_at_once_then_one_every_period() -> None:
    pacer = RelocalisationPacer(0.5)
    stamps = np.arange(0.0, 2.0, 1 / 30)
    sent = [t for t in stamps if pacer.due(False, float(t))]
    assert sent[0] == 0.0 and len(sent) == 4                 # 0, 0.5, 1.0, 1.5 s
    assert np.all(np.diff(sent) >= 0.5 - 1e-9)
    assert not pacer.due(True, 2.0)                          # tracked again: the loss ends
    assert pacer.due(False, 2.05)                            # a new loss: at once
    never = RelocalisationPacer(0.0)
    assert not any(never.due(False, float(t)) for t in stamps)
    with pytest.raises(ValueError, match=">= 0"):
        RelocalisationPacer(-1.0)


def test_a_request_carries_the_frames_features_as_the_edge_reads_them() -> None:
    rng = np.random.default_rng(0)
    n = 700
    payload = KeyFramePayload(41, 3, 1.25, np.eye(4), np.array([[525.0, 0, 319.5],
                                                                 [0, 525, 239.5], [0, 0, 1]]),
                              rng.uniform(0, 640, (n, 2)).astype(np.float32),
                              np.ones(n, np.float32),
                              rng.integers(0, 256, (n, 32), dtype=np.uint8),
                              np.zeros(n, np.uint64))
    data = serialize_message(relocalisation_request_message(payload, 1.25, "camera"))
    msg = deserialize_message(data, RelocalisationRequest)
    validate("twinslam_msgs/msg/RelocalisationRequest", msg)
    assert (msg.slot, msg.frame_id, msg.header.frame_id) == (3, 41, "camera")
    assert np.array_equal(np.asarray(msg.keypoints_xy).reshape(-1, 2), payload.keypoints)
    assert np.array_equal(np.asarray(msg.descriptors, np.uint8).reshape(-1, 32),
                          payload.descriptors)
    assert len(data) < 45 * n                                # ~40 bytes a feature, no image
    empty = relocalisation_request_message(
        KeyFramePayload(1, 0, 0.0, np.eye(4), np.eye(3), np.zeros((0, 2), np.float32),
                        np.zeros(0, np.float32), np.zeros((0, 32), np.uint8),
                        np.zeros(0, np.uint64)), 0.0, "camera")
    with pytest.raises(MessageError, match="no features"):
        validate("twinslam_msgs/msg/RelocalisationRequest", empty)
