"""Ending a live run's playback where the run chooses: at the end of a slot, once what it waits
for has happened.

A run that checks an event which comes after something slow — a twin's start, an outage
noticed, a restarted edge's first answer — cannot know beforehand how many frames that takes:
on a slower or busier machine it takes more. Such a run plays a generous number of frames and
ends the playback once the event came. The player ends on its live parameter ``stop_after``
(frames published); the run asks for the next slot boundary it believes the player has not
reached yet, and a boundary already passed is refused by the player with its count, so a
boundary a slot past that count is asked next (the monitor's own count lags the player's when
the camera's best-effort samples were lost, as on a link that was down). Every slot the device
closes is then full: its frame-count slot clock closes the last one as the player stops.
"""

from __future__ import annotations

import re

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future

#: the player's node name (the launchers start it as ``sequence_player``)
PLAYER = "sequence_player"
#: how the player's refusal says how far it is (twinslam/sequence_player/node.py)
PUBLISHED = re.compile(r"(\d+) frames are published already")


class PlaybackEnd:
    """Asks the player to stop after the first slot boundary it has not passed; ``frames`` is
    the count it accepted (None until then). ``poll`` runs between the monitor's spins."""

    def __init__(self, node: Node, slot_frames: int, most_frames: int | None,
                 player: str = PLAYER) -> None:
        if slot_frames <= 0:
            raise ValueError(f"slot_frames must be > 0, got {slot_frames}")
        self.client = AsyncParameterClient(node, player)
        self.slot_frames = slot_frames
        #: frames the player plays anyway (None: unknown): a boundary there needs no request
        self.most_frames = most_frames
        self.requested = False
        self.frames: int | None = None
        self.refused = 0                        #: boundaries the player had passed already
        self._asked = 0
        self._pending: Future | None = None

    def request(self) -> None:
        """End the playback at the next slot boundary (safe to call from any callback of the
        monitor's; the request goes out on the next ``poll``)."""
        self.requested = True

    @property
    def settled(self) -> bool:
        """Nothing to ask: no request, or the player accepted one, or it plays no further."""
        return not self.requested or self.frames is not None

    def answer_awaited(self) -> bool:
        """Whether a request is out whose answer has not come yet; one that came is taken
        (``frames`` set where the player accepted it). A player accepts an end and stops a
        few frames later, so it may exit before its answer is taken: the run waits for the
        answer past the player's exit, or it would count the slots of every frame the player
        might have played (a slower machine's monitor took the answer after the exit)."""
        if self._pending is not None and self._pending.done():
            self.poll(0)
        return self._pending is not None and not self._pending.done()

    def poll(self, played_at_least: int) -> None:
        """Send the request, or the next boundary after a refusal; ``played_at_least``: frames
        the monitor knows the player published (ground truth heard, slots summarised)."""
        if self.settled:
            return
        if self._pending is not None:
            if not self._pending.done():
                return
            answer, self._pending = self._pending.result(), None
            if answer is not None and answer.results and answer.results[0].successful:
                self.frames = self._asked
                return
            self.refused += 1
            said = PUBLISHED.search(answer.results[0].reason) if answer is not None \
                and answer.results else None
            if said:                # a slot past the player's count: the answer took time
                played_at_least = max(played_at_least, int(said.group(1)) + self.slot_frames)
        if not self.client.services_are_ready():
            return
        boundary = max(self._asked + self.slot_frames,
                       (played_at_least // self.slot_frames + 1) * self.slot_frames)
        if self.most_frames is not None and boundary >= self.most_frames:
            self.requested = False              # the playback ends there by itself
            return
        self._asked = boundary
        self._pending = self.client.set_parameters([Parameter("stop_after",
                                                              value=boundary)])
