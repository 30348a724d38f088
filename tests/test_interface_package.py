"""The twinslam_msgs interface package that `make` builds with rosidl from msg_schemas/msg."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

MSG_DIR = Path(__file__).resolve().parents[1] / "msg_schemas" / "msg"


def _declared_fields(path: Path) -> list[str]:
    """Field names of a .msg file, in order (comments and constants left out)."""
    names = []
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line and "=" not in line:
            names.append(re.split(r"\s+", line)[1])
    return names


@pytest.mark.parametrize("msg_file", sorted(MSG_DIR.glob("*.msg")), ids=lambda p: p.stem)
def test_every_msg_file_is_a_generated_class_with_its_fields(msg_file: Path) -> None:
    cls = getattr(importlib.import_module("twinslam_msgs.msg"), msg_file.stem)
    assert list(cls.get_fields_and_field_types()) == _declared_fields(msg_file)


def test_generated_messages_round_trip_through_rclpy_serialization() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from twinslam_msgs.msg import Keyframe, MapStats

    stats = MapStats(slot=7, policy="adapt", uncertainty=float("inf"), map_size=45)
    back = deserialize_message(serialize_message(stats), MapStats)
    assert (back.slot, back.policy, back.uncertainty, back.map_size) == (7, "adapt",
                                                                         float("inf"), 45)
    kf = Keyframe(frame_id=3, descriptors=bytes(range(64)))
    assert bytes(deserialize_message(serialize_message(kf), Keyframe).descriptors) == \
        bytes(range(64))
