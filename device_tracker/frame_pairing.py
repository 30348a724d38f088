"""Pairing colour and depth images by stamp, without DDS.

Each camera topic delivers in stamp order, but the two topics interleave as the executor takes
them: under load ten colour images may come before their depth images, so counting pending
frames is the wrong rule. A frame is ready when both halves are in, or hopeless when the other
topic has already delivered a newer stamp (its half will never come): a colour image is then
tracked without depth (no new points from it), a lone depth image dropped. With no depth topic
at all, colour waits at most ``max_pending`` frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

KINDS = ("color", "depth")


@dataclass(frozen=True)
class PairedFrame:
    stamp_key: int               #: nanoseconds, the frame's stamp
    color: Any | None            #: None: a depth image whose colour never came (drop it)
    depth: Any | None            #: None: track without depth
    newest_color: int            #: newest colour stamp seen, for the log of a dropped depth


class FramePairing:
    """Colour/depth halves by stamp; :meth:`ready` hands out frames oldest first."""

    def __init__(self, max_pending: int = 5) -> None:
        self.max_pending = max_pending
        self.pending: dict[int, dict[str, Any]] = {}
        self.newest = dict.fromkeys(KINDS, -1)          #: newest stamp seen per topic

    def add(self, kind: str, stamp_key: int, msg: Any) -> None:
        if kind not in KINDS:
            raise ValueError(f"image kind must be one of {KINDS}, got {kind!r}")
        self.pending.setdefault(stamp_key, {})[kind] = msg
        self.newest[kind] = max(self.newest[kind], stamp_key)

    def ready(self) -> Iterator[PairedFrame]:
        """Frames that are complete or can no longer be, oldest first; stops at the first
        that may still be completed."""
        while self.pending:
            oldest = min(self.pending)
            entry = self.pending[oldest]
            complete = "color" in entry and "depth" in entry
            missing = "depth" if "color" in entry else "color"
            hopeless = self.newest[missing] > oldest or (
                self.newest["depth"] < 0 and len(self.pending) > self.max_pending)
            if not complete and not hopeless:
                return
            del self.pending[oldest]
            yield PairedFrame(oldest, entry.get("color"), entry.get("depth"),
                              self.newest["color"])
