"""A protocol writer's log of its matched readers: one line a change in their number."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from twinslam.node_runtime.matched_readers import logging_matches


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
