"""The one error every uplink model raises for bad input, so callers catch one type."""

from __future__ import annotations


class ChannelError(ValueError):
    """A bad channel specification or trace file; the message names the file and line."""
