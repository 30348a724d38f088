"""``bench.loop_closer --words-from``: an archive searched under visual words learned in
another place, beside the exact search — what tells whether an edge process's one vocabulary
serves every device's place."""

from __future__ import annotations

import sys

import pytest

from bench import loop_closer

#: a dozen corridor keyframes searched under words of the synthetic room's (~11 000 points:
#: past the threshold below, so both archives search under words)
SMALL = ["synthetic-corridor:90", "--archive", "12", "--queries", "3", "--jobs", "1",
         "--exact-below", "3000"]


def _run(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["bench.loop_closer", *argv])
    loop_closer.main()


def test_an_archive_under_another_places_words_finds_what_exact_search_finds(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _run([*SMALL, "--words-from", "synthetic:90"], monkeypatch)
    out = capsys.readouterr().out
    assert "the words learned from synthetic:90" in out
    assert "learned again" not in out                  # searched under the room's words
    assert "the same place and pose (within 1 cm, 0.5°) 3;" in out
    assert "loops found: 3 of 3 queries; searching every point exactly 3" in out


def test_words_from_a_place_too_small_to_need_any_are_refused_with_the_reason(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(SystemExit) as stop:
        _run([*SMALL[:-2], "--words-from", "synthetic:4"], monkeypatch)
    assert "fewer than the 20000 that learn words" in str(stop.value.code)


def test_more_changing_jobs_than_a_small_archive_holds_are_refused_before_any_work(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Each changing job archives one keyframe and restores an older one: an archive of 12
    holds three such jobs (more failed, after the rest of the run, on a keyframe archived
    twice)."""
    with pytest.raises(SystemExit) as stop:
        _run(["synthetic-corridor:90", "--archive", "12", "--jobs", "4"], monkeypatch)
    assert stop.value.code == 2
    assert "--jobs: 1 to 3 for an archive of 12 keyframes, not 4" in capsys.readouterr().err
