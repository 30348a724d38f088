"""A device that started again told from a stray or repeated message: one old slot is
evidence, the new run's next slot proof; a slot of the running walk drops the evidence; where
the old run planned only its first slot, the new run's frames' stamps tell it from the
running walk's; an edge restarted from its checkpoint takes no repeated message for a new
run."""

from __future__ import annotations

from edge_mapper.restart_watch import Restart, RestartWatch, Verdict

#: a slot's frames: 30 at 30 Hz
FRAMES = 30


def _stamps(start_s: float) -> list[float]:
    return [start_s + i / 30.0 for i in range(FRAMES)]


class _Edge:
    """The slots an edge planned and closed, as the link asks the watch about them."""

    def __init__(self, watch: RestartWatch) -> None:
        self.watch, self.newest = watch, -1

    def send(self, slot: int, start_s: float) -> Verdict:
        stamps = _stamps(start_s)
        verdict = self.watch.summaries(slot, stamps, slot <= self.newest, self.newest)
        if verdict is Verdict.PLAN:
            self.watch.planned(stamps)
            self.newest = max(self.newest, slot)
        return verdict


def test_an_old_slot_then_the_next_one_is_a_restart_and_then_nothing_is_planned() -> None:
    edge = _Edge(RestartWatch())
    assert [edge.send(slot, 100.0 + slot) for slot in range(4)] == [Verdict.PLAN] * 4
    assert edge.send(0, 200.0) is Verdict.EVIDENCE
    assert edge.send(1, 201.0) is Verdict.RESTART
    assert edge.watch.restart == Restart(0, 3)
    assert edge.send(2, 202.0) is Verdict.IGNORED


def test_a_stray_old_slot_between_the_walks_slots_is_no_restart() -> None:
    edge = _Edge(RestartWatch())
    for slot in range(4):
        edge.send(slot, 100.0 + slot)
    assert edge.send(1, 101.0) is Verdict.EVIDENCE         # slot 1 again
    assert edge.send(4, 104.0) is Verdict.PLAN
    assert edge.send(5, 105.0) is Verdict.PLAN and edge.watch.restart is None


def test_a_repeated_newest_slot_then_the_next_one_is_no_restart() -> None:
    edge = _Edge(RestartWatch())
    for slot in range(4):
        edge.send(slot, 100.0 + slot)
    assert edge.send(3, 103.0) is Verdict.EVIDENCE
    assert edge.send(4, 104.0) is Verdict.PLAN and edge.watch.restart is None


def test_a_restart_after_the_old_runs_first_slot_is_told_by_the_new_frames_stamps() -> None:
    """The old run planned slot 0 only: the new run's slot 1 is ahead of every planned slot,
    as the old run's own slot 1 would be. Its slot 0 was captured after every planned frame,
    a repeated slot 0 was not."""
    edge = _Edge(RestartWatch())
    assert edge.send(0, 100.0) is Verdict.PLAN
    assert edge.send(0, 100.0) is Verdict.EVIDENCE          # the old slot 0 once more
    assert edge.send(1, 101.0) is Verdict.PLAN and edge.watch.restart is None
    again = _Edge(RestartWatch())
    assert again.send(0, 100.0) is Verdict.PLAN
    assert again.send(0, 300.0) is Verdict.EVIDENCE         # the new run's slot 0
    assert again.send(1, 301.0) is Verdict.RESTART
    assert again.watch.restart == Restart(0, 0)


def test_an_edge_restarted_from_its_checkpoint_takes_a_repeated_slot_for_no_restart() -> None:
    """The restarted edge planned slots up to 5 before it stopped (its checkpoint says so);
    the device sends its unanswered slot 5 again, then slot 6: the watch saw no planned frame
    and compares no stamps."""
    watch = RestartWatch()
    assert watch.summaries(5, _stamps(105.0), True, 5) is Verdict.EVIDENCE
    assert watch.summaries(6, _stamps(106.0), False, 5) is Verdict.PLAN
    assert watch.restart is None
