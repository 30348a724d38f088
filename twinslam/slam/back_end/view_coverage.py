"""Which of a device's frames a map already covers: a keyframe of the map stands where the
frame's camera stands and looks where it looks.

A device in a place another device mapped need not upload the views the shared map holds
already: the edge restores those keyframes where the device heads (the map update carries
them), and a frame next to one of them adds the same points seen from the same place. The
test is by pose, not by points: a device reports the few hundred map points it matched in a
frame, a small share of the corners it sees (docs/results/shared-map.md measured 10–42 % on
7-Scenes), so "the map holds most of the frame's points" would never hold where the map in
fact covers the view; an absolute count of the points other devices' keyframes made
does (``CoverageBounds.by_points``: where people walk one place each at their own height and
gaze, their frames track on each other's points though they seldom stand within the pose
bounds). Two cameras within ``max_m`` of each other turned by at most
``max_deg`` see much of one image of a room whose walls are a metre or more away; how much
is enough was measured, not reasoned: at 0.10 m and 10° a device walking where others walked
before uploaded nearly as much as alone (its keyframes stand about 0.4 m apart along a walk:
few of a slot's views fall that near one); 0.30 m and 20° saved 61–75 % of its uploads on the
corridor and 64 % on the 7-Scenes walk, with fewer frames off the map than the narrower
bounds (docs/results/shared-map.md, "The bounds of a covered view").

The same holds for a device coming back to where it was: its own keyframes of an earlier
visit stand there. Either way a keyframe beside a frame may hold little of what its camera
sees (a place mapped thinly, or while the camera moved fast), so a cover counts only for a
frame the map serves well enough (:attr:`CoverageBounds.min_points` of the points the device
matched, 50 by default: an absolute count, not a share). Which keyframes
cover is the edge's choice (``EdgeMapperCore.covered_frames``: lent ones, and with
``own_coverage_after_slots`` the device's own once they are a visit old); this module only
tells which frames a set of keyframe poses covers, and (``CoverageBounds.by_points``) which
frames share the cover's points with a set of keyframes' points.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from twinslam.slam.sorted_ids import held_counts


@dataclass(frozen=True)
class CoverageBounds:
    """How near a keyframe must be to a frame to cover its view (either of the first two 0:
    nothing covers), and how well the map must serve the frame for the cover to count."""

    max_m: float = 0.30          #: camera centres at most this far apart, metres
    max_deg: float = 20.0        #: the cameras turned by at most this, degrees
    #: the map points the frame must share with the map: a covered frame below it stays an
    #: upload candidate. Where a keyframe beside the frame holds little of what the camera
    #: sees (a place mapped thinly, or while the camera moved fast), a slot whose frames all
    #: rested on it uploads nothing and the next slot's frames may fall below the device's
    #: tracking floor (``MIN_INLIERS``, 15): at that floor, the device coming to a mapped
    #: 7-Scenes place lost 5.6 points more of its frames than alone in process. 50 (ORB-SLAM's
    #: bar for the tracking it trusts just after a relocalisation, set before any run) keeps
    #: thinly served frames candidates: no more frames lost than alone, in process and live,
    #: for 42 % (in process) and 68 % (live) fewer uploads than alone instead of 62 % and
    #: 80 %, and more of the edge's time a slot for the device in the shared place
    #: (docs/results/shared-map.md, "The margin as the default").
    min_points: int = 50
    #: also cover a frame by what the device matched, not where it stands: a frame that
    #: shares ``min_points`` of its reported points with the covering keyframes' points. On
    #: a long place each person walks at their own height, sway and gaze, seldom within the
    #: pose bounds of another's keyframes, yet their frames track on the points those
    #: keyframes made: four devices on walks of their own along the corridor uploaded a
    #: quarter to a third fewer keyframes than alone where the pose alone saved 5–8 %, two in
    #: a room, which the pose covers already, the same; but on the corridor's held-out walks
    #: the edge counted 0.6 points more of their frames lost than alone, so it is no default
    #: (docs/results/shared-map.md, "A cover judged by the points a frame tracks on"). Those
    #: frames fall where the device's map holds mostly other devices' copies, not after a
    #: slot it uploaded nothing in; gates on where the camera heads, on the slot's newest
    #: frames and keeping the device's newest keyframes lost as many ("Where the cover by
    #: points loses frames")
    by_points: bool = False

    def __post_init__(self) -> None:
        if not (self.max_m >= 0 and self.max_deg >= 0 and self.min_points >= 0):
            raise ValueError(f"coverage bounds are >= 0, got {self.max_m} m, {self.max_deg}°, "
                             f"{self.min_points} points")

    @property
    def enabled(self) -> bool:
        return self.max_m > 0 and self.max_deg > 0


def _near(frames: np.ndarray, keyframes: np.ndarray, bounds: CoverageBounds) -> np.ndarray:
    """(frames, keyframes) bools: which keyframe pose covers which frame pose (both N×4×4
    camera-to-map, one frame) within ``bounds``."""
    apart = np.linalg.norm(frames[:, None, :3, 3] - keyframes[None, :, :3, 3], axis=2)
    # trace(Rfᵀ Rk) for every pair: the angle between two rotations from its cosine
    trace = np.einsum("fij,kij->fk", frames[:, :3, :3], keyframes[:, :3, :3])
    cos_max = np.cos(np.radians(bounds.max_deg))
    turned_ok = (trace - 1.0) / 2.0 >= cos_max
    near: np.ndarray = (apart <= bounds.max_m) & turned_ok
    return near


def covered_views(frames: Mapping[int, np.ndarray], keyframes: Sequence[np.ndarray],
                  bounds: CoverageBounds) -> set[int]:
    """The ids of ``frames`` (id → 4×4 camera-to-map pose) that some pose of ``keyframes``
    (4×4 camera-to-map, the same frame) covers within ``bounds``."""
    if not frames or not len(keyframes) or not bounds.enabled:
        return set()
    ids = list(frames)
    f = np.asarray([frames[i] for i in ids], dtype=np.float64).reshape(-1, 4, 4)
    k = np.asarray(keyframes, dtype=np.float64).reshape(-1, 4, 4)
    hits = np.any(_near(f, k, bounds), axis=1)
    return {i for i, hit in zip(ids, hits.tolist(), strict=True) if hit}


def served_views(frames: Mapping[int, np.ndarray], covering_points: np.ndarray,
                 bounds: CoverageBounds) -> set[int]:
    """The ids of ``frames`` (id → the frame's reported map-point ids) that share at least
    ``bounds.min_points`` with ``covering_points`` (the points the covering keyframes see,
    ascending, without repeats): views the map holds by what the device matched there.
    Empty unless ``bounds.by_points``."""
    if not frames or not len(covering_points) or not bounds.by_points:
        return set()
    ids = list(frames)
    counts = held_counts([frames[i] for i in ids], covering_points)
    return {i for i, n in zip(ids, counts.tolist(), strict=True) if n >= bounds.min_points}


def first_cover(pose: np.ndarray, keyframes: Sequence[np.ndarray] | np.ndarray,
                bounds: CoverageBounds) -> int | None:
    """The index of the first of ``keyframes`` (4×4 camera-to-map poses, or an n×4×4 array of
    them) that covers the view from ``pose`` within ``bounds``; None: none does (or the
    bounds cover nothing)."""
    if not len(keyframes) or not bounds.enabled:
        return None
    f = np.asarray(pose, dtype=np.float64).reshape(1, 4, 4)
    k = np.asarray(keyframes, dtype=np.float64).reshape(-1, 4, 4)
    hits = np.flatnonzero(_near(f, k, bounds)[0])
    return int(hits[0]) if len(hits) else None


def uploads_for_new_views(uploads: int, new_views: int, views: int) -> int:
    """A slot's upload count where the shared map covers some of its views: the count the
    uplink allows for all ``views`` (the slot's tracked frames, Theorem 1) spent at the same
    density on the ``new_views`` the map lacks — rounded up, so a slot with any new view asks
    for one — and never more than them.

    Why a share and not the uplink's whole count: a device alone spreads Theorem 1's count
    over a slot of views that are all new to its map; a device in a mapped place whose slot
    holds three new views among thirty would otherwise spend the whole count on those three,
    uploading neighbouring frames of one view where alone it would upload one of them."""
    if uploads < 0 or new_views < 0 or views < new_views:
        raise ValueError(f"uploads {uploads}, new views {new_views} of {views}: "
                         "counts are >= 0 and new views at most the views")
    if new_views == 0:
        return 0
    return min(new_views, math.ceil(uploads * new_views / views - 1e-9))
