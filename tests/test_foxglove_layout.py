"""config/foxglove_layout.json opens a recorded run in Foxglove: every panel it arranges is
configured, and every topic and field it shows is one the nodes publish — a renamed topic or
MapStats field breaks this test, not a user's dashboard."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from msg_schemas import topics
from msg_schemas.interfaces import message_class

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "foxglove_layout.json"
#: the message type of each topic the layout plots
PLOTTED_TYPES = {"/edge/map_stats": "twinslam_msgs/msg/MapStats",
                 "/device/frame_summaries": "twinslam_msgs/msg/FrameSummaries",
                 "/device/uplink_throughput": "twinslam_msgs/msg/UplinkThroughput"}


def _panels(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    return _panels(node["first"]) + _panels(node["second"])


def test_the_layout_shows_topics_and_fields_the_nodes_publish() -> None:
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    published = {v if v.startswith("/") else f"/{v}" for k, v in vars(topics).items()
                 if k.isupper()}
    config = layout["configById"]
    shown = set(config["3D!map"]["topics"]) | {config["Image!camera"]["imageMode"]["imageTopic"]}
    assert shown <= published, shown - published
    assert {"/edge/map_points", "/edge/keyframes", "/edge/decisions", "/device/path",
            "/camera/ground_truth_path"} <= shown
    for panel in (p for p in panels if p.startswith("Plot!")):
        for path in config[panel]["paths"]:
            topic, _, field = path["value"].partition(".")
            assert topic in published, topic
            fields = message_class(PLOTTED_TYPES[topic]).get_fields_and_field_types()
            assert field in fields, f"{path['value']}: no field {field!r}"
