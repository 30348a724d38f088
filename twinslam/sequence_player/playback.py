"""What the player plays: a sequence's frames in a scenario's order, some of them blanked.

Map management only shows in tracking when the camera comes back to places it left (the
device then tracks against keyframes the edge chose to keep) and when tracking is lost and
must be regained against the edge's map. A sequence recorded once forward rarely
does either, so the player can

* play it **forward then backward** (``order: forward_backward``): every place is visited
  twice, the second time after the edge's map moved on, and the backward half's frames get
  fresh, evenly spaced stamps (the recorded period) so time keeps running forward;
* play it **backward** (``order: backward``), from its last frame to its first, with fresh
  stamps: a second device walking the same place from the other end, towards the first;
  ``order: backward_forward`` walks back to the first frame and on to the last again: a
  device that meets the first one and walks on, over the ground the other mapped;
* **blank** bursts of the walk's frames (``blank: "START:COUNT,..."``, positions in the
  order's walk): black colour and no depth readings — a covered lens — while the ground truth
  goes on, so the device loses tracking and must relocalise wherever the camera went meanwhile;
* play **one frame in every** few (``every: N``, ``phase: P``: the sequence's frames numbered
  P modulo N, counted from its first frame played), each at its time in the walk: a camera at
  a fraction of the recorded rate, the walk taking as long as recorded. Two devices
  replaying one sequence, whichever ways they walk it, see the very same images — a merge
  then pairs a frame with itself, which no two real cameras give; with ``every: 2`` and
  phases 0 and 1 one plays the even frames, the other the odd ones, and no image is shown
  twice.

Random access is needed for the backward half: dataset folders and the synthetic room have it,
a rosbag2 recording does not (play it forward, or record the scenario).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.sequences.frame import RandomAccessSequence, RgbdFrame, Sequence, SequenceError
from twinslam.slot_protocol import default_device, table1

ORDERS = ("forward", "forward_backward", "backward", "backward_forward")
#: the period assumed when a sequence has a single frame (no interval to measure)
DEFAULT_PERIOD_S = 1.0 / 30.0


def parse_bursts(text: str) -> tuple[tuple[int, int], ...]:
    """``"START:COUNT[,START:COUNT...]"`` (played positions) as sorted (start, count) pairs;
    "" is none. ValueError, saying what is wrong, otherwise."""
    bursts = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        start, sep, count = item.partition(":")
        try:
            pair = (int(start), int(count))
        except ValueError:
            pair = (-1, -1)
        if not sep or pair[0] < 0 or pair[1] < 1:
            raise ValueError(f"blank burst {item!r}: expected START:COUNT, START >= 0 and "
                             "COUNT >= 1 (played frames)")
        bursts.append(pair)
    return tuple(sorted(bursts))


def phase_for(residue: int, start: int, every: int) -> int:
    """The ``phase`` that plays the sequence's frames numbered ``residue`` modulo ``every``
    for a camera whose walk starts at the sequence's frame ``start`` (the player counts
    frames from there): how devices of one sequence are given alternate frames whatever
    their starts."""
    return (residue - start) % every


def played_slot(slot_frames: int, frame_rate_hz: float, every: int) -> tuple[int, float]:
    """The slot's frames and the nominal frame rate of a device whose camera plays one frame
    in ``every``: both divided by ``every``, so that a slot lasts as long and asks for its
    uploads as often as at every frame. Raises :class:`ValueError` where the slot's frames do
    not split ``every`` ways."""
    if slot_frames % every:
        raise ValueError(f"a slot of {slot_frames} frames does not split {every} ways into "
                         "whole frames played")
    return slot_frames // every, frame_rate_hz / every


def played_device_slot(device_params: Mapping[str, object], every: int = 1, rate: float = 1.0
                       ) -> tuple[int, float]:
    """What a device is told of its slot where the player plays one frame in ``every`` at
    ``rate`` × the recorded speed: ``slot_frames`` and ``frame_rate_hz`` as ``device_params``
    gives them (a parameter file's device section; the device's defaults for what it leaves
    out), the rate × ``rate`` — a slot is cut by frame stamps, and replayed faster they come
    faster — and both divided by ``every`` (:func:`played_slot`). Raises :class:`ValueError`
    where the slot does not split ``every`` ways or ``rate`` is not a positive number."""
    if not rate > 0 or not np.isfinite(rate):
        raise ValueError(f"rate must be a positive number (x the recorded speed), got {rate}")
    slot_frames = float(str(device_params.get("slot_frames", default_device.SLOT_FRAMES)))
    if not slot_frames.is_integer() or slot_frames < 1:
        raise ValueError(f"slot_frames must be a whole number of frames, got {slot_frames:g}")
    return played_slot(int(slot_frames), float(str(device_params.get(
        "frame_rate_hz", table1.FRAME_RATE_HZ))) * rate, every)


@dataclass(frozen=True)
class Playback:
    """The order frames are played in, which of them are played (the sequence's frames
    numbered ``phase`` modulo ``every``) and the walk's positions that are blanked."""

    order: str = "forward"
    blank: tuple[tuple[int, int], ...] = ()
    every: int = 1
    phase: int = 0

    def __post_init__(self) -> None:
        if self.order not in ORDERS:
            raise ValueError(f"order must be one of {', '.join(ORDERS)}, got {self.order!r}")
        if self.every < 1 or not 0 <= self.phase < self.every:
            raise ValueError(f"every must be >= 1 and phase from 0 to every - 1, got every "
                             f"{self.every}, phase {self.phase}")

    def walk(self, n: int) -> list[int]:
        """The sequence's frame at each position of the order's walk (the turning frame
        once), every frame of it."""
        forward = list(range(n))
        if self.order == "backward":
            return forward[::-1]
        if self.order == "backward_forward":
            return forward[::-1] + forward[1:]
        return forward if self.order == "forward" else forward + forward[-2::-1]

    def plays(self, source: int) -> bool:
        """Whether the sequence's frame ``source`` is one this camera plays: chosen by the
        frame, not by where the walk has it, so that a device at phase 0 and one at phase 1
        never show one image whichever ways they walk."""
        return source % self.every == self.phase

    def played(self, n: int) -> list[tuple[int, int]]:
        """(the walk's position, the sequence's frame) of each frame played, in order."""
        return [(at, source) for at, source in enumerate(self.walk(n)) if self.plays(source)]

    def source_indices(self, n: int) -> list[int]:
        """The sequence's frame played at each played position."""
        return [source for _, source in self.played(n)]

    def blanked(self, position: int) -> bool:
        return any(start <= position < start + count for start, count in self.blank)


def blank_frame(frame: RgbdFrame) -> RgbdFrame:
    """The frame as a covered camera sees it: black, no depth reading; its pose stays true."""
    depth = np.zeros_like(frame.depth) if frame.depth is not None else None
    return dataclasses.replace(frame, color=np.zeros_like(frame.color), depth=depth,
                               name=f"{frame.name} (blanked)")


class PlayedSequence:
    """A sequence reader seen through a :class:`Playback`; iterates :class:`RgbdFrame` s whose
    ``index`` is the played position and whose stamps increase. A frame keeps the time of
    its place in the walk: played one in ``every``, the walk lasts as long."""

    def __init__(self, reader: Sequence, playback: Playback) -> None:
        if playback.order != "forward" and not isinstance(reader, RandomAccessSequence):
            raise SequenceError(f"{reader.path}: a {reader.kind} sequence plays forward only "
                                f"(order {playback.order!r} needs a dataset folder or the "
                                "synthetic room)")
        self.reader, self.playback = reader, playback
        walk = len(playback.walk(len(reader)))
        #: (the walk's position, the sequence's frame) of each played position
        self.played = playback.played(len(reader))
        self.positions = [source for _, source in self.played]
        stamps = np.asarray(reader.stamps, dtype=np.float64)
        steps = np.diff(stamps)
        steps = steps[steps > 0]
        self.period_s = float(np.median(steps)) if steps.size else DEFAULT_PERIOD_S
        self.first_stamp = float(stamps[0])
        self.span_s = (float(stamps[-1] - stamps[0]) if playback.order == "forward"
                       else (walk - 1) * self.period_s)

    @property
    def kind(self) -> str:
        return str(self.reader.kind)

    @property
    def path(self) -> Path:
        return self.reader.path

    @property
    def skipped(self) -> list[str]:
        """Frames of the last pass that could not be read."""
        return list(self.reader.skipped)

    def __len__(self) -> int:
        return len(self.positions)

    def __iter__(self) -> Iterator[RgbdFrame]:
        for at, frame in self._frames():
            yield blank_frame(frame) if self.playback.blanked(at) else frame

    def _frames(self) -> Iterator[tuple[int, RgbdFrame]]:
        """(the walk's position, the frame) of each frame played."""
        playback = self.playback
        if playback.order == "forward":           # streams (bags too), stamps as recorded
            for frame in self.reader:
                if playback.plays(frame.index):
                    yield frame.index, (frame if playback.every == 1 else dataclasses.replace(
                        frame, index=frame.index // playback.every))
            return
        reader = self.reader
        assert isinstance(reader, RandomAccessSequence)     # checked in __init__
        reader.skipped = []
        for position, (at, source) in enumerate(self.played):
            read = reader.read(source)
            if read is not None:
                yield at, dataclasses.replace(read, index=position,
                                              stamp=self.first_stamp + at * self.period_s)
