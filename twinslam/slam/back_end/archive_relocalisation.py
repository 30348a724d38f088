"""Relocalising a lost device's frame against the edge's archive (Edge-SLAM's server-side
relocalisation, ORB-SLAM's Relocalization over a keyframe database).

A device tracks against the managed map it was sent; once it walks into a place the map
evicted, nothing it holds can relocalise it. The edge still remembers the place
(:mod:`twinslam.slam.back_end.keyframe_archive`). From the lost frame's ORB features alone (no
image:
a few tens of kilobytes) the archive's place recognition proposes the keyframes that share the
most descriptors with it; each candidate's map points, with those of the archived keyframes
that observe the same points (its covisible neighbours: a frame seldom sees exactly one
keyframe's view), are matched by descriptor (Lowe's ratio test) and the pose solved by PnP
RANSAC and refined on the inliers. Candidates are solved in the order of their votes (none
with fewer than VOTES_TO_SOLVE of the gate's inliers in votes), and the first whose pose has
``min_inliers`` inliers — the device's own gate
(:class:`~twinslam.slam.front_end.tracking.TrackingConfig`) — is accepted, as ORB-SLAM's
relocalisation and loop closing stop at the first candidate that passes: the candidates after
it were solved before 2026-12-01 only to keep the one with the most inliers: 27 of the loop
search's 90 PnPs over ``bench.edge_work``'s walk forward and back (timed once, 610 of their
1777 ms). The device checks a
relocalised pose once more against where it last tracked; a loop is confirmed by later
keyframes (:mod:`twinslam.slam.back_end.loop_closing`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.descriptor_matching import match_descriptors

#: the PnP solvers: OpenCV's USAC (the default) or its classic RANSAC over EPnP hypotheses
#: (the solver before 2026-11-30, kept to compare: ``bench.archive_pnp``)
SOLVERS = ("usac", "epnp")
#: hypotheses either solver may draw
PNP_HYPOTHESES = 200
#: the most PnP inliers a candidate finds a vote it had, rounded up: 1.9 over every candidate
#: that passed its gate in the runs VOTES_TO_SOLVE names
INLIERS_PER_VOTE = 2
#: a candidate with fewer votes than this share of the gate's inliers is not solved. Its
#: votes are the frame's features whose nearest point of the whole archive it observed; its
#: PnP matches each feature among its group's points alone, so its inliers may exceed its
#: votes — by at most 1.9 times over every candidate that passed its gate in a walk of
#: six devices over three places and the 7-Scenes walk from its two ends (60 of 466
#: solves, 2026-12-04) — never near the four times this share leaves. A look for a merge in
#: another place's map proposed candidates of 1-17 votes, each solved in vain before (a
#: descriptor match over its group's points, 3 ms): the look's place search ends there now
VOTES_TO_SOLVE = 0.25
#: a screened search (:attr:`ArchiveRelocalisationConfig.screen_votes`) first searches every
#: SCREEN_STRIDE-th feature of the frame: a quarter of the search, spread over the image (the
#: extractor lists its features cell by cell)
SCREEN_STRIDE = 4


@dataclass(frozen=True)
class ArchiveRelocalisationConfig:
    candidates: int = 3              #: archived keyframes place recognition proposes
    min_inliers: int = 20            #: the gate (as the device's reloc_min_inliers)
    neighbours: int = 4              #: archived keyframes sharing the most points added
    ratio: float = 0.8               #: Lowe's ratio test on Hamming distances
    max_hamming: int = 64            #: of 256 bits
    reprojection_px: float = 3.0     #: RANSAC's inlier threshold
    solver: str = "usac"             #: one of SOLVERS
    #: votes the best place must have among every SCREEN_STRIDE-th feature before the whole
    #: frame is searched (0: the whole frame at once); see :func:`screen_for`
    screen_votes: int = 0

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"solver {self.solver!r}: one of {', '.join(SOLVERS)}")


@dataclass(frozen=True)
class ArchiveLocation:
    """Where a lost frame was found in the archive, or why it was not."""

    pose: np.ndarray | None          #: camera-to-map (None: not found)
    inliers: int                     #: of the accepted candidate (none: the most any had)
    #: the candidate keyframe whose pose was accepted; where none was, the one place
    #: recognition ranked first (-1: none proposed)
    keyframe: int
    keyframes: tuple[int, ...]       #: the archived keyframes its points came from
    reason: str = ""                 #: why not found ("" when found)

    @property
    def found(self) -> bool:
        return self.pose is not None


def locate_in_archive(archive: KeyFrameArchive, points_xy: np.ndarray, descriptors: np.ndarray,
                      intrinsics: np.ndarray,
                      config: ArchiveRelocalisationConfig = ArchiveRelocalisationConfig(),
                      eligible: Callable[[int], bool] | None = None) -> ArchiveLocation:
    """The pose of a frame with ORB features (``points_xy`` (n, 2) pixels, ``descriptors``
    (n, 32) uint8) seen by camera ``intrinsics``, among the archive's keyframes — those
    ``eligible`` says may be (a loop's: only keyframes far older than the new one)."""
    xy = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    desc = np.ascontiguousarray(descriptors, dtype=np.uint8).reshape(-1, 32)
    if len(xy) != len(desc):
        raise ValueError(f"{len(xy)} keypoints but {len(desc)} descriptors")
    if config.screen_votes and len(desc):
        sample = archive.recognise(desc[::SCREEN_STRIDE], top=1, eligible=eligible)
        if not sample or sample[0][1] < config.screen_votes:
            place, votes = sample[0] if sample else (-1, 0)
            return ArchiveLocation(None, 0, place, (),
                                   f"the best place has {votes} votes among every "
                                   f"{SCREEN_STRIDE}th feature, fewer than the screen's "
                                   f"{config.screen_votes}")
    proposed = archive.recognise(desc, top=config.candidates, eligible=eligible) \
        if len(desc) else []
    if not proposed:
        return ArchiveLocation(None, 0, -1, (), "the archive recognises no place in the frame")
    solvable = [kf_id for kf_id, votes in proposed
                if votes >= VOTES_TO_SOLVE * config.min_inliers]
    if not solvable:
        return ArchiveLocation(None, 0, proposed[0][0], (),
                               f"the best place has {proposed[0][1]} votes, too few for "
                               f"{config.min_inliers} inliers")
    best = ArchiveLocation(None, 0, proposed[0][0], (), "")
    solved: set[frozenset[int]] = set()
    recognised: tuple[int, ...] = ()
    for kf_id in solvable:
        group = [k for k in _with_neighbours(archive, kf_id, config.neighbours)
                 if eligible is None or eligible(k)]
        recognised = recognised or tuple(group)
        # candidates that are each other's neighbours often bring the same keyframes (a
        # place seen from a few keyframes): their points, and so their PnP, are one problem,
        # solved once for the candidate with the most votes
        if frozenset(group) in solved:
            continue
        solved.add(frozenset(group))
        pose, inliers = _solve(archive, group, xy, desc, intrinsics, config)
        if inliers > best.inliers:
            best = ArchiveLocation(pose, inliers, kf_id, tuple(group), "")
        if best.pose is not None and best.inliers >= config.min_inliers:
            return best                  # the first candidate through the gate
    if best.pose is None or best.inliers < config.min_inliers:
        # no pose holds: the place named is the one recognition ranked first, not the one
        # whose few (chance) inliers came out highest
        return ArchiveLocation(None, best.inliers, proposed[0][0], recognised,
                               f"{best.inliers} inliers, fewer than {config.min_inliers}")
    return best


def screen_for(votes: int, miss: float = 1e-3) -> int:
    """The screen (:attr:`ArchiveRelocalisationConfig.screen_votes`) that a place with
    ``votes`` votes in the whole frame fails with probability ``miss`` at most: each of its
    votes falls among the screened features with probability 1 / SCREEN_STRIDE, and the
    screen asks for the most votes the sample falls short of no more often than that
    (binomial). A place with fewer votes may be screened out: the caller asks for ``votes``
    where no fewer can pass its gate."""
    p = 1.0 / SCREEN_STRIDE
    below = 0.0                       # P(sample votes < k), k = 0, 1, …
    for k in range(votes + 1):
        below_next = below + math.comb(votes, k) * p ** k * (1 - p) ** (votes - k)
        if below_next > miss:
            return k
        below = below_next
    return votes


def _usac(threshold_px: float) -> cv2.UsacParams:
    """OpenCV's USAC for the archive's PnP, within the hypotheses the classic RANSAC is given.
    Classic EPnP RANSAC draws five matches a hypothesis: on the 7-Scenes walk's loop searches
    (30-60 % inliers among 50-300 matches) it spent 6-11 ms a solve, and on the synthetic
    room with four of five matches wrong it found no pose (``bench.archive_pnp``). USAC
    scores with MSAC, optimises the best model locally on its inliers and stops once
    confident: on the same loop searches it found as many inliers or more in two thirds of
    the time (measured 2026-11-30). Its random state is fixed: the same matches give the same
    pose."""
    params = cv2.UsacParams()
    params.threshold = threshold_px
    params.confidence = 0.999
    params.maxIterations = PNP_HYPOTHESES
    return params


def _with_neighbours(archive: KeyFrameArchive, kf_id: int, count: int) -> list[int]:
    """``kf_id`` and the ``count`` archived keyframes sharing the most of its points."""
    shared = sorted(((s, k) for k, s in archive.shared_with(kf_id).items()),
                    key=lambda sk: (-sk[0], sk[1]))
    return [kf_id] + [k for s, k in shared[:count] if s > 0]


def _solve(archive: KeyFrameArchive, group: list[int], xy: np.ndarray, desc: np.ndarray,
           intrinsics: np.ndarray, config: ArchiveRelocalisationConfig
           ) -> tuple[np.ndarray | None, int]:
    """PnP RANSAC of the frame against the points of the archived keyframes ``group`` (each
    map point once): (camera-to-map or None, inliers)."""
    kfs = [archive.get(kf_id) for kf_id in group]
    if not kfs:
        return None, 0
    # each map point once, as the group first lists it
    _, first = np.unique(np.concatenate([kf.point_ids for kf in kfs]), return_index=True)
    first.sort()
    if len(first) < config.min_inliers:
        return None, 0
    world = np.concatenate([kf.positions for kf in kfs]).astype(np.float64)[first]
    point_desc = np.concatenate([kf.descriptors for kf in kfs])[first]
    f_idx, p_idx = match_descriptors(desc, np.ascontiguousarray(point_desc, dtype=np.uint8),
                                     config.max_hamming, config.ratio)
    if len(f_idx) < max(config.min_inliers, 6):
        return None, 0
    obj, img = world[p_idx], xy[f_idx]
    k = np.asarray(intrinsics, dtype=np.float64)
    if config.solver == "usac":
        ok, _, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, k, None,
                                                    params=_usac(config.reprojection_px))
    else:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, k, None,
                                                 iterationsCount=PNP_HYPOTHESES,
                                                 reprojectionError=config.reprojection_px,
                                                 confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 6:
        return None, 0 if inl is None else len(inl)
    mask = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[mask], img[mask], k, None, rvec, tvec)
    projected, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
    err = np.linalg.norm(projected.reshape(-1, 2) - img, axis=1)
    rot, _ = cv2.Rodrigues(rvec)
    cam = obj @ rot.T + tvec.ravel()
    inliers = int(np.sum((err <= config.reprojection_px) & (cam[:, 2] > 0)))
    cw = np.eye(4)
    cw[:3, :3], cw[:3, 3] = rot, tvec.ravel()
    return np.linalg.inv(cw), inliers
