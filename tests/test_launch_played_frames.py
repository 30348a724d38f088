"""What a ``twinslam launch`` run says it plays: the frames that really play, not ``--frames``
as given (a shorter sequence, ``-1`` for all, a walk played forward then back)."""

from __future__ import annotations

import argparse

import pytest

from twinslam.cli.commands.launch import played_frames
from twinslam.live.scenarios import SCENARIOS
from twinslam.sequences.frame import SequenceError


def _args(frames: int, start: int = 0, sequence: str = "synthetic:150") -> argparse.Namespace:
    return argparse.Namespace(sequence=sequence, frames=frames, start=start)


def test_the_header_counts_the_frames_that_play() -> None:
    forward, revisit = SCENARIOS["forward"], SCENARIOS["revisit"]
    assert played_frames(_args(600), forward) == "150 frames"       # the sequence is shorter
    assert played_frames(_args(-1), forward) == "150 frames"        # all of it
    assert played_frames(_args(40, start=20), forward) == "40 frames"
    assert played_frames(_args(-1, start=100), forward) == "50 frames"
    assert played_frames(_args(100), revisit) == "199 frames (100 forward then back)"


def test_a_range_the_sequence_does_not_hold_is_refused() -> None:
    with pytest.raises(SequenceError, match="bad frame range"):
        played_frames(_args(10, start=150), SCENARIOS["forward"])
