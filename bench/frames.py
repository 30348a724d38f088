"""Frames a bench reads in any order, by index, and the error that names what it cannot read:
a sequence a bench walks forward and back (or revisits) must be a dataset folder or a
synthetic world — a bag plays forward only — and a frame that cannot be read stops the bench,
named, instead of a traceback on ``None``."""

from __future__ import annotations

from twinslam.sequences.frame import RandomAccessSequence, RgbdFrame, Sequence


def random_access(reader: Sequence, sequence: str) -> RandomAccessSequence:
    """``reader`` (opened from ``sequence``) as a sequence read by index; SystemExit, naming
    ``sequence``, where it plays forward only."""
    if not isinstance(reader, RandomAccessSequence):
        raise SystemExit(f"{sequence}: a dataset folder or a synthetic world is needed "
                         "(a bag plays forward only)")
    return reader


def frame_at(reader: RandomAccessSequence, index: int, sequence: str) -> RgbdFrame:
    """Frame ``index`` of ``reader``; SystemExit, naming it and ``sequence``, where it cannot
    be read."""
    frame = reader.read(index)
    if frame is None:
        raise SystemExit(f"{sequence}: frame {index} cannot be read")
    return frame
