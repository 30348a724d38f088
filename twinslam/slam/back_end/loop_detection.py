"""Finding a loop: a keyframe just integrated that the archive recognises as a place seen long
before, confirmed by geometry.

ORB-SLAM's LoopClosing asks its keyframe database for candidates that share words with the new
keyframe but are not its covisible neighbours, then solves a similarity between the two and
accepts it with enough inliers. Here the archive's place recognition proposes the archived
keyframes far older than the new one (``min_gap`` keyframe ids: not the recent walk, which
the new keyframe resembles trivially), and the new keyframe's features are solved against
their points by PnP RANSAC, accepted on ``MIN_INLIERS`` inliers
(:func:`~twinslam.slam.back_end.archive_relocalisation.locate_in_archive`, the relocalisation
the edge already runs for a lost device): a look-alike place whose points do not fit one
camera pose is refused. With depths (an RGB-D keyframe) the loop is then measured between the
two keyframes alone, from PnP's start: the new keyframe's features matched to the points the
old keyframe saw, both lifted by their own depths, fitted rigidly
(:func:`measure_between`; ORB-SLAM closes RGB-D loops with its Sim3 solver at scale one, the
same 3D–3D fit). PnP mistakes a small turn for a sideways step in front of one wall, and the
map's points may have moved since the old keyframe saw them; the depths do neither
(docs/results/map-consistency.md). An accepted loop gives the pose the old place puts the new
keyframe at; its relative pose to the old keyframe is the loop factor of the pose graph
(:mod:`twinslam.slam.back_end.pose_graph`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from twinslam.slam.back_end.archive_relocalisation import (
    ArchiveRelocalisationConfig,
    locate_in_archive,
)
from twinslam.slam.back_end.depth_alignment import DepthAlignment, align_with_depth
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.descriptor_matching import match_descriptors
from twinslam.slam.projection_matching import back_project

#: a loop joins keyframes at least this many keyframe ids apart (ids are frame indices: 10 s
#: of a 30 Hz camera); the recent walk is no loop
MIN_GAP = 300
#: PnP inliers a loop needs: more than a relocalisation's 20 — a relocalised pose is checked
#: again by the device's own gate, a loop moves the whole map at once. On the live revisit
#: walk (docs/results/loop-closing.md) loops on 20 inliers left two runs of ten 0.6 and 1.06 m
#: off; ORB-SLAM accepts a loop on 40 or more matches after its guided search
MIN_INLIERS = 50


@dataclass(frozen=True)
class LoopCandidate:
    """A loop the geometric check accepted, or why none was."""

    old: int                           #: the archived keyframe of the place (-1: none)
    pose: np.ndarray | None            #: the new keyframe's camera-to-map as the old place puts it
    measured: np.ndarray | None        #: old⁻¹ · pose: the loop factor's relative pose
    inliers: int
    reason: str = ""

    @property
    def found(self) -> bool:
        return self.pose is not None


def detect_loop(archive: KeyFrameArchive, keyframe: int, points_xy: np.ndarray,
                descriptors: np.ndarray, intrinsics: np.ndarray, min_gap: int = MIN_GAP,
                config: ArchiveRelocalisationConfig | None = None,
                depths: np.ndarray | None = None) -> LoopCandidate:
    """The loop keyframe ``keyframe`` (its ORB features ``points_xy``, ``descriptors`` and,
    from a depth camera, their ``depths``) closes with an archived keyframe at least
    ``min_gap`` ids older, if the geometry confirms one."""
    return recognise_place(archive, points_xy, descriptors, intrinsics, config, depths,
                           eligible=lambda k: k <= keyframe - min_gap)


def recognise_place(archive: KeyFrameArchive, points_xy: np.ndarray, descriptors: np.ndarray,
                    intrinsics: np.ndarray, config: ArchiveRelocalisationConfig | None = None,
                    depths: np.ndarray | None = None,
                    eligible: Callable[[int], bool] | None = None,
                    archive_intrinsics: np.ndarray | None = None) -> LoopCandidate:
    """The place of ``archive`` a keyframe (its ORB features ``points_xy``, ``descriptors``
    and, from a depth camera, their ``depths``) sees, among the keyframes ``eligible`` says
    may be (None: all), confirmed by geometry: PnP with ``MIN_INLIERS`` inliers, then — with
    depths — the relative pose to the recognised keyframe measured from the two keyframes'
    depths (:func:`measure_between`). A loop looks among the walk's own old keyframes; a map
    merge among another device's (:mod:`twinslam.slam.back_end.map_merging`), whose camera,
    ``archive_intrinsics``, took its keyframes (None: the keyframe's own camera, a walk's
    own archive); an archived keyframe that carries intrinsics of its own (another device's
    copy) was taken with those."""
    config = config or ArchiveRelocalisationConfig(min_inliers=MIN_INLIERS)
    found = locate_in_archive(archive, points_xy, descriptors, intrinsics, config,
                              eligible=eligible)
    if not found.found or found.pose is None:
        return LoopCandidate(-1, None, None, found.inliers, found.reason or "no eligible place")
    old = archive.get(found.keyframe)
    measured = np.linalg.inv(old.pose) @ found.pose
    if depths is None or not np.any(np.asarray(depths) > 0):    # no depth camera: PnP's
        return LoopCandidate(found.keyframe, found.pose, measured, found.inliers)
    between = measure_between(old, points_xy, descriptors, depths, intrinsics, measured, config,
                              old.camera(intrinsics if archive_intrinsics is None
                                         else archive_intrinsics))
    if between.pose is None:
        return LoopCandidate(-1, None, None, between.inliers,
                             f"{between.inliers} of the matches with keyframe {old.id} agree "
                             f"in depth, fewer than {config.min_inliers}")
    return LoopCandidate(found.keyframe, old.pose @ between.pose, between.pose,
                         between.inliers)


def measure_between(old: ArchivedKeyFrame, points_xy: np.ndarray, descriptors: np.ndarray,
                    depths: np.ndarray, intrinsics: np.ndarray, start: np.ndarray,
                    config: ArchiveRelocalisationConfig,
                    old_intrinsics: np.ndarray | None = None) -> DepthAlignment:
    """The new keyframe's pose relative to the ``old`` one (old⁻¹ · new) from the two
    keyframes' own depth measurements alone, started at ``start`` (PnP's): the new
    keyframe's features matched to the points the old one saw, both lifted by their depths
    into their cameras — the new one's of ``intrinsics``, the old one's of
    ``old_intrinsics`` (None: the same camera). No map point's position enters — a point a
    bundle adjustment or a fusion moved since the old keyframe saw it cannot bend the
    loop."""
    f_idx, p_idx = match_descriptors(np.ascontiguousarray(descriptors, dtype=np.uint8),
                                     old.descriptors, config.max_hamming, config.ratio)
    if len(f_idx) < config.min_inliers:
        return DepthAlignment(None, len(f_idx), float("nan"))
    z = np.asarray(depths, dtype=np.float64).reshape(-1)[f_idx]
    k, in_camera = np.asarray(intrinsics, dtype=np.float64), np.eye(4)
    k_old = k if old_intrinsics is None else np.asarray(old_intrinsics, dtype=np.float64)
    new_points = back_project(np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)[f_idx],
                              np.where(z > 0, z, np.nan), k, in_camera)
    seen = old.measurements[p_idx]
    old_points = back_project(seen[:, :2], seen[:, 2], k_old, in_camera)
    return align_with_depth(start, new_points, old_points, config.min_inliers)
