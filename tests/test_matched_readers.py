"""A protocol writer's log of its matched readers, and a reader's of its writers: one line a change
in their number."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from twinslam.node_runtime.matched_readers import logging_matches, logging_writer_matches


class _Node:
    """What ``logging_matches`` asks of a node: its topic names resolved, and its logger."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def resolve_topic_name(self, topic: str) -> str:
        return f"/{topic}"

    def get_logger(self) -> Any:
        return SimpleNamespace(info=self.lines.append)


def test_readers_that_match_at_once_are_logged_once_and_each_change_after() -> None:
    node = _Node()
    matched = logging_matches(node, "udt/rate_latent").matched  # type: ignore[arg-type]
    assert matched is not None
    # eight readers matched together: eight events, each reporting the count of all eight
    for count in [8] * 8 + [7, 7, 8]:
        matched(SimpleNamespace(current_count=count))
    assert node.lines == ["udt/rate_latent: 8 reader(s) matched",
                          "udt/rate_latent: 7 reader(s) matched",
                          "udt/rate_latent: 8 reader(s) matched"]


def test_a_reader_logs_its_writers_as_a_writer_logs_its_readers() -> None:
    """The edge's summaries reader says when a device's writer matched it: what that writer
    publishes from then on reaches the edge (a volatile reader that matches late skips what
    was written before)."""
    node = _Node()
    matched = logging_writer_matches(node, "device/frame_summaries").matched  # type: ignore[arg-type]
    assert matched is not None
    for count in (1, 1, 0, 1):
        matched(SimpleNamespace(current_count=count))
    assert node.lines == ["device/frame_summaries: 1 writer(s) matched",
                          "device/frame_summaries: 0 writer(s) matched",
                          "device/frame_summaries: 1 writer(s) matched"]
