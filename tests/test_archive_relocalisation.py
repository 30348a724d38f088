"""Relocalising a lost frame against the edge's archive, on real ORB features of the synthetic
room: the pose of a frame near an archived keyframe is found to within centimetres, also
when most of its matches are wrong, and a hand-made wrong match (the frame's features with
their pixel positions shuffled) is refused by the inlier gate, as is a frame of no archived
place."""

from __future__ import annotations

import numpy as np
import pytest

from bench.archive_pnp import room_archive
from twinslam.slam.back_end.archive_relocalisation import (
    ArchiveRelocalisationConfig,
    locate_in_archive,
)
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.front_end.orb_extractor import OrbExtractor

KEYFRAMES = range(0, 300, 30)


@pytest.fixture(scope="module")
def room() -> tuple[object, KeyFrameArchive, OrbExtractor]:
    """Keyframes every 30 frames of the room's walk, archived with their points placed by
    depth and the true pose (as the edge's map would hold them; ``bench.archive_pnp``'s)."""
    seq, archive = room_archive()
    return seq, archive, OrbExtractor()


@pytest.mark.parametrize("query", [4, 127, 251])
def test_a_frame_near_an_archived_keyframe_is_found_where_it_is(
        room: tuple[object, KeyFrameArchive, OrbExtractor], query: int) -> None:
    seq, archive, orb = room
    frame = seq.read(query)                                    # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    found = locate_in_archive(archive, feats.points, feats.descriptors,
                              seq.intrinsics)                  # type: ignore[attr-defined]
    assert found.found, found.reason
    assert found.keyframe in KEYFRAMES and abs(found.keyframe - query) <= 30
    assert found.inliers >= 50
    moved = np.linalg.norm(found.pose[:3, 3] - frame.pose[:3, 3])  # type: ignore[index]
    assert moved < 0.03, moved


def test_a_wrong_match_and_an_unknown_place_are_refused(
        room: tuple[object, KeyFrameArchive, OrbExtractor]) -> None:
    seq, archive, orb = room
    feats = orb.extract(seq.read(127).color)                  # type: ignore[attr-defined]
    shuffled = np.random.default_rng(0).permutation(feats.points)
    wrong = locate_in_archive(archive, shuffled, feats.descriptors,
                              seq.intrinsics)                 # type: ignore[attr-defined]
    assert not wrong.found and wrong.pose is None
    assert wrong.keyframe == 120                             # recognised, but no pose holds
    assert wrong.inliers < ArchiveRelocalisationConfig().min_inliers
    assert "fewer than 20" in wrong.reason
    noise = np.random.default_rng(1).integers(0, 256, (500, 32), dtype=np.uint8)
    nowhere = locate_in_archive(archive, feats.points[:500], noise,
                                seq.intrinsics)              # type: ignore[attr-defined]
    assert not nowhere.found and nowhere.keyframe == -1
    assert "recognises no place" in nowhere.reason
    with pytest.raises(ValueError, match="keypoints but"):
        locate_in_archive(archive, feats.points[:10], feats.descriptors[:9],
                          seq.intrinsics)                    # type: ignore[attr-defined]


@pytest.mark.parametrize("query", [4, 127, 251])
def test_a_frame_whose_matches_are_mostly_wrong_is_still_found(
        room: tuple[object, KeyFrameArchive, OrbExtractor], query: int) -> None:
    """Four of every five features moved to another feature's pixel (their descriptors kept,
    so they still match, at the wrong place), as where a place's look changed between two
    visits: the pose is found on the fifth that is right, within 2.5 cm. (Five-match EPnP
    hypotheses, 200 of them, found no pose in any of the three.)"""
    seq, archive, orb = room
    frame = seq.read(query)                                    # type: ignore[attr-defined]
    feats = orb.extract(frame.color)
    rng = np.random.default_rng(0)
    xy = feats.points.copy()
    moved = rng.random(len(xy)) < 0.8
    xy[moved] = rng.permutation(xy[moved])
    found = locate_in_archive(archive, xy, feats.descriptors,
                              seq.intrinsics)                  # type: ignore[attr-defined]
    assert found.found, found.reason
    assert abs(found.keyframe - query) <= 30
    off = np.linalg.norm(found.pose[:3, 3] - frame.pose[:3, 3])  # type: ignore[index]
    assert off < 0.025, off


def _solves_counted(monkeypatch: pytest.MonkeyPatch) -> list[list[int]]:
    """Each candidate group the place search solves from now on (its PnP), in order."""
    import twinslam.slam.back_end.archive_relocalisation as relocalisation

    solved: list[list[int]] = []
    solve = relocalisation._solve

    def counted(*args: object, **kwargs: object) -> tuple[np.ndarray | None, int]:
        solved.append(list(args[1]))                          # type: ignore[call-overload]
        return solve(*args, **kwargs)                         # type: ignore[arg-type]

    monkeypatch.setattr(relocalisation, "_solve", counted)
    return solved

def test_the_search_stops_at_the_first_candidate_whose_pose_passes(
        room: tuple[object, KeyFrameArchive, OrbExtractor],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Candidates are solved in the order of their votes and the first one through the gate
    is the answer (ORB-SLAM's relocalisation and loop closing stop there too): a frame the
    best-voted candidate places is solved once, not once per candidate; a frame no pose
    holds for is solved against every candidate before it is refused."""
    seq, archive, orb = room
    solved = _solves_counted(monkeypatch)
    feats = orb.extract(seq.read(127).color)                  # type: ignore[attr-defined]
    proposed = archive.recognise(feats.descriptors, top=3)
    assert len(proposed) == 3
    found = locate_in_archive(archive, feats.points, feats.descriptors,
                              seq.intrinsics)                 # type: ignore[attr-defined]
    assert found.found and found.keyframe == proposed[0][0] and len(solved) == 1
    solved.clear()
    shuffled = np.random.default_rng(0).permutation(feats.points)
    refused = locate_in_archive(archive, shuffled, feats.descriptors,
                                seq.intrinsics)               # type: ignore[attr-defined]
    assert not refused.found and len(solved) == len({frozenset(g) for g in solved}) >= 2


def test_a_place_with_too_few_votes_for_the_gate_is_not_solved(
        room: tuple[object, KeyFrameArchive, OrbExtractor],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame that shares only a few features with the archive (another place's, seen by a
    merge look: 1-17 votes) is refused without a PnP — no candidate has a quarter of the
    gate's inliers in votes — and says so; under a gate its votes can reach, the best
    candidate is solved as before."""
    seq, archive, orb = room
    solved = _solves_counted(monkeypatch)
    feats = orb.extract(seq.read(127).color)                  # type: ignore[attr-defined]
    rng = np.random.default_rng(2)
    elsewhere = rng.integers(0, 256, feats.descriptors.shape, dtype=np.uint8)
    elsewhere[:12] = feats.descriptors[:12]                   # a dozen features in common
    votes = archive.recognise(elsewhere, top=1)[0][1]
    gate = 4 * votes + 4                                      # a quarter of it: above the votes
    config = ArchiveRelocalisationConfig(min_inliers=gate)
    refused = locate_in_archive(archive, feats.points, elsewhere, seq.intrinsics,  # type: ignore[attr-defined]
                                config)
    assert not refused.found and solved == []
    assert f"{votes} votes, too few for {gate} inliers" in refused.reason
    lenient = ArchiveRelocalisationConfig(min_inliers=max(1, votes * 4 // 2))
    locate_in_archive(archive, feats.points, elsewhere, seq.intrinsics,  # type: ignore[attr-defined]
                      lenient)
    assert solved                                             # the candidate was solved


def test_the_screen_passes_a_place_with_the_votes_asked_but_once_in_a_thousand() -> None:
    """Each of a place's votes falls among the screened quarter of the features with
    probability 1/4: the screen for v votes is the most sample votes a place of v falls short
    of with probability 1e-3 at most (binomial), so a place the caller needs passes all but
    that often, and one vote more would miss it more often."""
    from scipy.stats import binom

    from twinslam.slam.back_end.archive_relocalisation import SCREEN_STRIDE, screen_for

    for votes in (10, 25, 50, 100):
        screen = screen_for(votes)
        assert binom.cdf(screen - 1, votes, 1 / SCREEN_STRIDE) <= 1e-3 < \
            binom.cdf(screen, votes, 1 / SCREEN_STRIDE)
    assert screen_for(50) == 4 and screen_for(1) == 0


def test_a_screened_search_ends_at_the_sample_where_the_place_has_too_few_votes(
        room: tuple[object, KeyFrameArchive, OrbExtractor],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame of another place (a dozen features in common) screened: only every fourth of
    its features is searched, nothing solved, and the reason names the screen; a frame of the
    room passes it and is found where the unscreened search finds it, on as many inliers."""
    import twinslam.slam.back_end.archive_relocalisation as relocalisation

    seq, archive, orb = room
    searched: list[int] = []
    recognise = archive.recognise

    def counted(descriptors: np.ndarray, *args: object, **kwargs: object
                ) -> list[tuple[int, int]]:
        searched.append(len(descriptors))
        return recognise(descriptors, *args, **kwargs)       # type: ignore[arg-type]

    monkeypatch.setattr(archive, "recognise", counted)
    feats = orb.extract(seq.read(127).color)                  # type: ignore[attr-defined]
    elsewhere = np.random.default_rng(2).integers(0, 256, feats.descriptors.shape,
                                                  dtype=np.uint8)
    elsewhere[:12] = feats.descriptors[:12]
    screened = ArchiveRelocalisationConfig(min_inliers=50, screen_votes=4)
    refused = locate_in_archive(archive, feats.points, elsewhere, seq.intrinsics,  # type: ignore[attr-defined]
                                screened)
    assert not refused.found and "among every 4th feature" in refused.reason
    assert searched == [len(range(0, len(elsewhere), relocalisation.SCREEN_STRIDE))]
    searched.clear()
    found = locate_in_archive(archive, feats.points, feats.descriptors,
                              seq.intrinsics, screened)  # type: ignore[attr-defined]
    plain = locate_in_archive(archive, feats.points, feats.descriptors, seq.intrinsics,  # type: ignore[attr-defined]
                              ArchiveRelocalisationConfig(min_inliers=50))
    assert found.found and searched[1] == len(feats.descriptors)
    assert (found.keyframe, found.inliers) == (plain.keyframe, plain.inliers)
