"""Our CDR codec against rosbags' ROS 2 Jazzy serialisation, the independent reference.

The wire format decides whether a real ROS 2 node can read what twinslam writes: every byte of
our encoding must equal what ROS 2 (here: rosbags) produces for the same content, and bytes
rosbags produced must decode to the same content.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msg_schemas import CdrError, custom_message_names, deserialize, new, serialize, typestore
from tests.message_strategies import message_strategy

CHECKED_TYPES = ["sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                 "geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Path",
                 "rmw_dds_common/msg/ParticipantEntitiesInfo", *custom_message_names()]


@pytest.mark.parametrize("type_name", CHECKED_TYPES)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bytes_equal_rosbags_and_decode_rosbags_bytes(type_name: str, data: st.DataObject) -> None:
    store = typestore()
    msg = data.draw(message_strategy(type_name))
    reference = bytes(store.serialize_cdr(msg, type_name))
    assert serialize(msg) == reference
    decoded = deserialize(reference, type_name)
    # Re-encoding by the reference proves the decoded content equals the original content.
    assert bytes(store.serialize_cdr(decoded, type_name)) == reference


def test_image_of_a_real_camera_size_round_trips_without_copying_pixels() -> None:
    pixels = np.random.default_rng(0).integers(0, 255, 480 * 640 * 3, dtype=np.uint8)
    img = new("sensor_msgs/msg/Image", height=480, width=640, encoding="rgb8", step=1920,
              data=pixels)
    payload = serialize(img)
    assert payload == bytes(typestore().serialize_cdr(img, "sensor_msgs/msg/Image"))
    back = deserialize(payload, "sensor_msgs/msg/Image")
    assert np.array_equal(back.data, pixels)
    assert back.data.base is not None  # a view on the received bytes, not a copy


@settings(max_examples=15, deadline=None)
@given(msg=message_strategy("twinslam_msgs/msg/Keyframe"))
def test_every_truncation_is_a_clean_cdr_error(msg: object) -> None:
    payload = serialize(msg)
    for cut in range(0, len(payload) - 1, max(1, len(payload) // 60)):
        try:
            deserialize(payload[:cut], "twinslam_msgs/msg/Keyframe")
        except CdrError:
            continue
        # A prefix may decode only if what was cut was trailing alignment padding.
        assert len(payload) - cut <= 8


def test_sequence_length_claiming_4_gb_is_refused_before_allocating() -> None:
    msg = new("twinslam_msgs/msg/MapUpdate", point_ids=np.arange(3, dtype=np.uint64),
              point_positions=np.zeros(9), point_descriptors=np.zeros(96, np.uint8))
    payload = bytearray(serialize(msg))
    # keyframe_ids is the first sequence after the header (std_msgs/Header) + 2 x uint32.
    header_len = 4 + 8 + 4 + len(b"\x00") + 3  # stamp, frame_id length + NUL + pad
    offset = header_len + 8
    payload[offset:offset + 4] = (0xFFFFFFF0).to_bytes(4, "little")
    with pytest.raises(CdrError, match="truncated"):
        deserialize(bytes(payload), "twinslam_msgs/msg/MapUpdate")


def test_big_endian_and_garbage_headers_are_refused() -> None:
    good = serialize(new("std_msgs/msg/String", data="hi"))
    with pytest.raises(CdrError, match="big-endian"):
        deserialize(b"\x00\x00" + good[2:], "std_msgs/msg/String")
    with pytest.raises(CdrError, match="encapsulation"):
        deserialize(b"\x07\x07" + good[2:], "std_msgs/msg/String")
    with pytest.raises(CdrError, match="NUL"):
        deserialize(good[:-1] + b"x", "std_msgs/msg/String")


def test_encoding_refuses_values_that_do_not_fit_the_field() -> None:
    with pytest.raises(CdrError, match="uint8"):
        serialize(new("sensor_msgs/msg/Image", is_bigendian=300))
    with pytest.raises(CdrError, match="9"):
        serialize(new("sensor_msgs/msg/CameraInfo", k=np.zeros(4)))
