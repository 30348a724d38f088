"""Telling a device that started again from a stray or repeated message.

A device that restarts (its app, its computer) while its edge runs on counts its slots and
frame ids from 0 again. While a device runs its slots only go forward, so summaries of a slot
the edge planned and closed already (:meth:`~edge_mapper.edge_core.EdgeMapperCore.is_restart`)
are a new run's — or a stray message: one repeated, or one whose slot number a fault changed.
Setting the map aside on a stray message would lose the map to bad input, so one such slot is
evidence, not proof: the restart is taken once the new run's next slot follows it, and a slot
of the running walk in between drops the evidence.

Where the old run planned only its first slot, the new run's next slot is ahead of everything
planned, as the running walk's next slot would be: the slot numbers cannot tell the two apart.
The frames' capture stamps can: the new run's frames were captured after every frame the edge
planned, a repeated message's were not. The stamps are compared only when this watch saw the
planned frames itself: an edge restarted from its checkpoint has not, and a message the device
sends again after that restart must not pass for a new run.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass


class Verdict(enum.Enum):
    """What the link does with one message of frame summaries."""

    PLAN = "plan"              #: the running walk's slot: planned as ever
    EVIDENCE = "evidence"      #: an old slot, left unanswered: a restart if its next follows
    RESTART = "restart"        #: the device started again: served afresh from its next slot
    IGNORED = "ignored"        #: a restart was taken already: nothing is answered until then


@dataclass(frozen=True)
class Restart:
    """A restart taken: the slot the device came back at, and the newest the edge planned."""

    slot: int
    newest_planned: int


class RestartWatch:
    """One device's summaries watched for a restart (the link asks it about each message)."""

    def __init__(self) -> None:
        self.restart: Restart | None = None
        #: the old slot that may be a new run's first, and its frames' oldest stamp
        self._evidence: tuple[int, float] | None = None
        #: the newest capture stamp among the frames of the slots planned (seconds; -inf:
        #: none planned by this watch)
        self._planned_stamp = -math.inf

    def planned(self, stamps: Iterable[float]) -> None:
        """A slot whose frames were captured at ``stamps`` (seconds) was planned."""
        self._planned_stamp = max(self._planned_stamp, max(stamps, default=-math.inf))

    def summaries(self, slot: int, stamps: Iterable[float], closed_already: bool,
                  newest_planned: int) -> Verdict:
        """The verdict on summaries of ``slot`` with frames captured at ``stamps``:
        ``closed_already`` whether the edge planned and closed that slot, ``newest_planned``
        the newest slot it planned."""
        if self.restart is not None:
            return Verdict.IGNORED
        follows = self._evidence is not None and slot == self._evidence[0] + 1
        if closed_already:
            if follows:
                return self._take(newest_planned)
            self._evidence = (slot, min(stamps, default=-math.inf))
            return Verdict.EVIDENCE
        if follows and slot > newest_planned and self._evidence is not None and \
                self._evidence[1] > self._planned_stamp > -math.inf:
            return self._take(newest_planned)
        self._evidence = None
        return Verdict.PLAN

    def _take(self, newest_planned: int) -> Verdict:
        assert self._evidence is not None
        self.restart = Restart(self._evidence[0], newest_planned)
        self._evidence = None
        return Verdict.RESTART
