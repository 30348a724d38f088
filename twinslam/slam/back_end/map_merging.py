"""Two devices' maps of one place made one: the joining map's frame found in the other's.

Every device the edge serves starts a map of its own, in a frame of its own (its first
camera's). When one device walks where another has mapped, the maps describe one place in two
frames, and content one user anchors appears elsewhere to the other. ORB-SLAM3's Atlas
merges two maps where place recognition relates them; here, as for a loop
(:mod:`twinslam.slam.back_end.loop_detection`), a keyframe the joining device's edge map
just integrated is looked for among the other map's keyframes — its archive and its managed
map, its store's :meth:`~twinslam.slam.back_end.keyframe_store.KeyFrameStore.snapshot` —
and accepted on geometry: PnP with a loop's inliers, then the
relative pose to the recognised keyframe measured from the two keyframes' depths. The
keyframe's pose as the other map puts it, times its pose in its own map⁻¹, is the
**alignment**: the rigid motion that carries the joining map's frame into the other's.

A merge is confirmed as a loop is (:class:`~twinslam.slam.back_end.loop_closing.
LoopConfirmation`, ORB-SLAM3's temporal consistency): later keyframes of the joining map must
find the other map again where the first detection's alignment puts them. A poster that hangs
in two rooms fools one keyframe; the next ones look past it. There is no drift bound as a
loop's (:func:`~twinslam.slam.back_end.loop_closing.beyond_drift`): two maps' frames are
arbitrarily apart.

The merge itself is the joining map moved as a whole by the alignment
(:meth:`~twinslam.slam.back_end.map_back_end.MapBackEnd.align`): its device gets it as a
frame correction in its next map update, as it gets a loop's, and from then on both
devices' poses are in one frame — the place's, the first map's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from twinslam.slam.back_end.archive_relocalisation import (
    INLIERS_PER_VOTE,
    ArchiveRelocalisationConfig,
    screen_for,
)
from twinslam.slam.back_end.foreign_keyframes import (
    all_under_tag,
    foreign_tag,
    is_foreign,
    source_id,
    tag_of,
)
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import KeyFrameMap
from twinslam.slam.back_end.keyframe_store import KeyFrameStore
from twinslam.slam.back_end.loop_closing import (
    CONFIRMATIONS,
    LoopConfirmation,
    LoopQuery,
    walk_length,
)
from twinslam.slam.back_end.loop_detection import MIN_INLIERS, LoopCandidate, recognise_place
from twinslam.slam.back_end.map_back_end import FollowedLoop, MapBackEnd
from twinslam.slam.back_end.point_fusion import FusionConfig, MapPoints, duplicates_in_view
from twinslam.slam.back_end.view_coverage import CoverageBounds, first_cover
from twinslam.slam.camera import Camera

#: the PnP inliers each detection of a merge needs by default: twice a loop's MIN_INLIERS.
#: A merge places a whole map by one keyframe's geometry; live on the 7-Scenes walk from its
#: two ends, merging on 100 instead of 50 came 6-8 slots later and left both devices nearer
#: the truth (ATE -0.58 and -0.26 cm, ten seeds). The two devices' agreement on the same
#: frames was not told apart (-0.37 cm [-1.37, +0.62]); the figure over every frame after
#: the merge fell 1.1-1.2 cm, most of it the frames a later merge leaves out
#: (docs/results/shared-map.md)
MERGE_MIN_INLIERS = 2 * MIN_INLIERS

#: a view lent once by default (:func:`lend_from`'s ``views``): another device's keyframe is
#: not lent where a copy the borrower holds stands within LENT_VIEW_M and LENT_VIEW_DEG of it
#: (0 m: every keyframe is lent)
LENT_VIEW_M = 0.0
LENT_VIEW_DEG = 10.0


def lent_view(max_m: float, max_deg: float) -> CoverageBounds | None:
    """The bounds within which a copy a borrower holds declines another device's keyframe
    (:func:`lend_from`'s ``views``), or None where they cover nothing: every keyframe lent."""
    bounds = CoverageBounds(max_m, max_deg)
    return bounds if bounds.enabled else None


@dataclass(frozen=True)
class MapMerge:
    """A confirmed merge: where the joining map's keyframe found the other map."""

    joining: int                      #: the joining map's keyframe that confirmed it
    place: int                        #: the other map's keyframe it found
    #: 4×4 rigid motion carrying the joining map's frame into the other map's
    alignment: np.ndarray
    inliers: int

    def inverse(self) -> MapMerge:
        """The same merge seen from the other map: its keyframe joining, the motion back."""
        return MapMerge(self.place, self.joining, np.linalg.inv(self.alignment), self.inliers)


class MergeFinder:
    """Looks for another map's place in one joining map's new keyframes, and confirms it
    (one per pair of maps; the confirmation's state is kept across calls). Each detection
    needs ``min_inliers`` PnP inliers (MERGE_MIN_INLIERS by default: a whole map placed by
    one keyframe's geometry waits for a place both maps see well).

    The place search is screened (:func:`~twinslam.slam.back_end.archive_relocalisation.
    screen_for`): a keyframe's every fourth feature is searched first, and only where the
    other map's best place has the votes there that a place of ``min_inliers`` inliers shows
    but once in a thousand fewer is the whole keyframe searched. Most looks of a device whose
    place no other device shares search another place's map, whose best place has a few
    votes; the screen ends each such look at a quarter of its search."""

    def __init__(self, confirmations: int = CONFIRMATIONS,
                 min_inliers: int = MERGE_MIN_INLIERS) -> None:
        self.confirmation = LoopConfirmation(confirmations)
        self.min_inliers = min_inliers
        self.search = ArchiveRelocalisationConfig(
            min_inliers=MIN_INLIERS,
            screen_votes=screen_for(math.ceil(min_inliers / INLIERS_PER_VOTE)))
        self.candidates = 0               #: keyframes whose geometry found the other map
        #: keyframes whose geometry found the other map at a loop's inliers, below the
        #: merge's gate too: the place seen, if not well enough to merge on
        self.sightings = 0
        self.last: LoopCandidate | None = None   #: what the last keyframe found, or why not

    def offer(self, other: KeyFrameArchive, query: LoopQuery,
              joining_poses: Mapping[int, np.ndarray], intrinsics: np.ndarray,
              other_intrinsics: np.ndarray | None = None) -> MapMerge | None:
        """Keyframe ``query`` of the joining map (its poses ``joining_poses``, id →
        camera-to-map, the query's among them; its camera ``intrinsics``) looked for in
        ``other`` (a store's snapshot, its keyframes taken by a camera of
        ``other_intrinsics``; None: the same): the merge, once confirmed; None until then."""
        pose = joining_poses[query.keyframe]
        candidate = recognise_place(other, query.points_xy, query.descriptors, intrinsics,
                                    self.search, depths=query.depths,
                                    archive_intrinsics=other_intrinsics)
        self.sightings += candidate.found
        if candidate.found and candidate.inliers < self.min_inliers:
            candidate = LoopCandidate(-1, None, None, candidate.inliers,
                                      f"{candidate.inliers} inliers, fewer than the merge's "
                                      f"{self.min_inliers}")
        self.last = candidate
        self.candidates += candidate.found
        pending = self.confirmation.pending
        walked = 0.0 if pending is None else \
            walk_length(joining_poses, pending.query, query.keyframe)
        if not self.confirmation.judge(query.keyframe, candidate, pose, walked):
            return None
        assert candidate.pose is not None            # judge confirms found candidates only
        return MapMerge(query.keyframe, candidate.old, candidate.pose @ np.linalg.inv(pose),
                        candidate.inliers)


def welded(keyframe: ArchivedKeyFrame, source: int, into: KeyFrameMap, camera: Camera,
           slot: int, config: FusionConfig | None = None,
           points: MapPoints | None = None) -> ArchivedKeyFrame:
    """Another device's keyframe (of source map ``source``, already in this map's frame) as
    map ``into`` adopts it: its id and its points' ids tagged with the source's
    (:mod:`~twinslam.slam.back_end.foreign_keyframes`) — except each point that duplicates a
    point of ``into``, which takes that point's id: seen where that point projects into the
    keyframe, alike in descriptor (Lowe's ratio) and within ``max_gap_m`` of it, as a
    restored keyframe's points are fused (:mod:`~twinslam.slam.back_end.point_fusion`;
    ORB-SLAM3 welds two merged maps the same way). The welded points are what connect the
    adopted keyframe to the map's own: without them it shares no point with them, and a
    restore of it would leave the map in two pieces. A point the source map had adopted
    itself (a third device's, tagged already: the source's own keyframes observe the copies'
    points they matched) keeps its id — tagged again, its tag would read as yet another
    device's and alias that device's point of the same number. ``points``: ``into``'s
    points as they are, read once for a batch of keyframes (None: read here). ``camera``:
    the adopting map's device's; the keyframe's own intrinsics, which a lent keyframe
    carries (:func:`lend_from`), are what its pixels are projected with."""
    tag = foreign_tag(source)
    ids = keyframe.point_ids.astype(np.int64)
    ids = all_under_tag(ids, tag)
    rows = np.flatnonzero(np.isfinite(keyframe.measurements[:, 0]))
    # a point the keyframe holds already under that id (a third device's copy both maps
    # adopted) is no duplicate to weld another of its corners to: a keyframe sees a point once
    held = set(ids.tolist())
    taken_by = Camera(keyframe.camera(camera.intrinsics), camera.shape)
    for row, point in duplicates_in_view(keyframe.pose, keyframe.measurements[rows, :2],
                                         keyframe.descriptors[rows], keyframe.positions[rows],
                                         points or MapPoints.every(into),
                                         taken_by, config):
        if point not in held:
            ids[rows[row]] = point
            held.add(point)
    return dataclasses.replace(keyframe, id=keyframe.id | tag, point_ids=ids,
                               archived_slot=slot)


def _unlent(lender: Lender, borrower: KeyFrameStore) -> tuple[list[ArchivedKeyFrame], list[int]]:
    """The lender map's own keyframes (not those it adopted itself) neither lent to the
    borrower (its store ``borrower``) nor declined for a copy it still holds: what another
    map in its frame has yet to adopt — (its archive's, its managed map's ids: these are
    copied once lent, not every round a lender offers them). A declined keyframe whose cover
    left the borrower, or that left the lender, is no longer declined."""
    own = lender.back_end.store
    for kf_id, cover in list(lender.declined.items()):
        if cover not in borrower or kf_id not in own:
            del lender.declined[kf_id]
    skip = lender.lent | lender.declined.keys()
    back_end = lender.back_end
    return ([kf for kf in back_end.archive if kf.id not in skip and not is_foreign(kf.id)],
            [k for k in back_end.map.keyframes if k not in skip and not is_foreign(k)])


@dataclass(frozen=True)
class Lending:
    """What one lending did to the borrower (:func:`lend_from`)."""

    followed: int                      #: the lender's loops the borrower has followed now
    adopted: int                       #: the lender's keyframes adopted this time
    #: each lender's loop followed this time, what it moved
    moves: tuple[FollowedLoop, ...] = ()
    #: copies of the lender's keyframes that went back to it this time, unseen for long
    returned: int = 0


#: which of another map's keyframes (each given by its points' positions, in the borrower's
#: frame) the borrower's camera sees from where it is heading, one answer a keyframe
InView = Callable[[Sequence[np.ndarray]], Sequence[bool]]
#: a lender's keyframes on offer: its archive's, and the ids of its managed map's (copied only
#: once lent)
Offer = tuple[list[ArchivedKeyFrame], list[int]]


@dataclass(frozen=True)
class Lender:
    """A map lending to another in its frame: what the borrower has had of it so far."""

    back_end: MapBackEnd
    source: int                        #: its source index (its copies' tag)
    lent: set[int]                     #: its keyframes the borrower adopted (grows)
    followed: int                      #: its loops the borrower's copies followed
    #: its keyframes offered and not lent yet (out of the borrower's view), by the borrower's
    #: slot each was first offered at: a copy counts as adopted then (its lender was there
    #: then, whenever the borrower comes to see it)
    offered: dict[int, int] = field(default_factory=dict)
    #: its keyframes lent, by the borrower's last slot that held or saw its copy (in the
    #: borrower's slice, or in view): a copy unseen for long goes back (:func:`lend_from`)
    seen: dict[int, int] = field(default_factory=dict)
    #: its keyframes not lent for a copy the borrower holds of their view already
    #: (:func:`lend_from` with ``views``), each by that copy's (tagged) id: offered again once
    #: that copy has left the borrower
    declined: dict[int, int] = field(default_factory=dict)


def lend_from(borrower: MapBackEnd, lenders: list[Lender], slot: int,
              in_view: InView | None = None, unseen_slots: int = 0,
              views: CoverageBounds | None = None) -> list[Lending]:
    """One lending round from every map of the borrower's place (``lenders``, all in its
    frame), before the borrower's next map version: first each lender's loops
    since those the borrower followed move the copies lent before and the borrower's keyframes
    tied to them (:func:`follow_lender_loops`), then each lender's own keyframes not lent yet
    are welded and adopted (:func:`_unlent`, :func:`adopt_lent`) — in that order,
    since a keyframe lent after a loop carries its correction already. The borrower's
    points, which the loops may move and welding does not, are read once for every lender's
    keyframes: a place of eight devices welds seven lenders' keyframes a slot. What each
    lender's lending did, in their order.

    With ``in_view``, only the keyframes the borrower's camera sees from where it heads are
    lent; the others wait, offered again each round, until it heads where they are. A
    borrower then welds what its device comes to, not every keyframe its place's devices
    make (each of which every other device's map welded: a place's welding grew with the
    square of its devices), and a copy carries the lender's loops up to the round it was
    lent in. Each keyframe counts as adopted at the round it was first offered in
    (:attr:`Lender.offered`), as lent at once: a loop across devices closes only with the
    keyframes of a device that was there first (:meth:`MapBackEnd._across`).

    With ``in_view`` and ``unseen_slots``, a copy goes back the other way too: one in the
    borrower's archive that its device has neither held nor seen for ``unseen_slots`` slots
    leaves it (:meth:`MapBackEnd.release_copies`) and is offered again, with the slot it was
    first offered at, while its lender still keeps the original. A borrower then holds
    the copies of where its device is and was lately, not of every place it ever passed: each
    copy it holds is welded, archived, searched by its loop closer and the looks, and moved by
    every lender loop. Where its device comes back, the copy is lent anew: as the lender has
    it now, welded to the borrower's points as they are now."""
    follows = [follow_lender_loops(borrower, lender.back_end, lender.source, lender.followed)
               for lender in lenders]
    offers = [_unlent(lender, borrower.store) for lender in lenders]
    for lender, (archived, held) in zip(lenders, offers, strict=True):
        _note_offered(lender.offered, [*(kf.id for kf in archived), *held], slot)
    if in_view is not None:
        offers = _seen_only(lenders, offers, in_view)
    if views is not None and views.enabled:
        offers = _new_views_only(borrower, lenders, offers, views)
    # a keyframe of a lender's managed map is copied only once it is lent; each carries the
    # lender's camera, which took it (the borrower's may be another model)
    unlent = [[_taken_by(kf, lender.back_end.device.k)
               for kf in archived + [ArchivedKeyFrame.of(lender.back_end.map, k, slot)
                                     for k in held]]
              for lender, (archived, held) in zip(lenders, offers, strict=True)]
    points = MapPoints.every(borrower.map) if any(unlent) else None
    adopted = [adopt_lent(borrower, keyframes, lender.source, lender.lent, slot, points,
                          lender.offered)
               for lender, keyframes in zip(lenders, unlent, strict=True)]
    returned = _return_unseen(borrower, lenders, slot, in_view, unseen_slots) \
        if in_view is not None and unseen_slots > 0 else [0] * len(lenders)
    return [Lending(followed, count, moves, back)
            for (followed, moves), count, back in zip(follows, adopted, returned,
                                                      strict=True)]


def _taken_by(keyframe: ArchivedKeyFrame, intrinsics: np.ndarray) -> ArchivedKeyFrame:
    """A lender's own ``keyframe`` marked as taken by the lender's camera (``intrinsics``),
    which the borrower's need not be."""
    if keyframe.intrinsics is not None:
        return keyframe
    return dataclasses.replace(keyframe,
                               intrinsics=np.asarray(intrinsics, dtype=np.float64).copy())


def _return_unseen(borrower: MapBackEnd, lenders: list[Lender], slot: int, in_view: InView,
                   unseen_slots: int) -> list[int]:
    """The borrower's archived copies of each lender's keyframes that it has neither held in
    its slice nor seen (``in_view``) for ``unseen_slots`` slots, released
    (:meth:`MapBackEnd.release_copies`) where the lender still keeps the original: each
    offered again from the slot it was adopted at (its first offer's), lent anew once the
    borrower sees it. How many went back to each lender."""
    by_tag = {foreign_tag(lender.source): lender for lender in lenders}
    for k in borrower.map.keyframes:
        if is_foreign(k) and (lender := by_tag.get(tag_of(k))) is not None:
            lender.seen[source_id(k)] = slot
    archived = [kf for kf in borrower.archive
                if is_foreign(kf.id) and tag_of(kf.id) in by_tag]
    if not archived:
        return [0] * len(lenders)
    unseen = []
    for kf, seen in zip(archived, in_view([kf.positions for kf in archived]), strict=True):
        lender, own = by_tag[tag_of(kf.id)], source_id(kf.id)
        if seen:
            lender.seen[own] = slot
        elif lender.seen.setdefault(own, slot) <= slot - unseen_slots and \
                own in lender.back_end.store:
            unseen.append(kf.id)
    returned = dict.fromkeys(by_tag, 0)
    for copy, adopted in borrower.release_copies(unseen).items():
        lender, own = by_tag[tag_of(copy)], source_id(copy)
        lender.lent.discard(own)
        lender.seen.pop(own, None)
        lender.offered[own] = adopted
        returned[tag_of(copy)] += 1
    return [returned[foreign_tag(lender.source)] for lender in lenders]


def _note_offered(offered: dict[int, int], keyframes: list[int], slot: int) -> None:
    """``keyframes`` (a lender's, not lent yet) offered at ``slot`` unless offered before;
    those offered before that the lender no longer has forgotten."""
    now = set(keyframes)
    for gone in [k for k in offered if k not in now]:
        del offered[gone]
    for k in now:
        offered.setdefault(k, slot)


def _new_views_only(borrower: MapBackEnd, lenders: list[Lender], offers: list[Offer],
                    views: CoverageBounds) -> list[Offer]:
    """Each lender's ``offers`` whose view no copy the borrower holds covers within
    ``views`` — nor a keyframe kept before it in this round, lenders in their order, the
    archived before the managed map's — the others declined (:attr:`Lender.declined`, by the
    covering copy's tagged id)."""
    held = [(k, pose) for k, pose in borrower.store.poses().items() if is_foreign(k)]
    covers = [k for k, _ in held]
    # the covering poses as one array, the copies held first and each kept offer after them
    # (filled as they are kept, not stacked again for every offer)
    poses = np.empty((len(held) + sum(len(a) + len(m) for a, m in offers), 4, 4))
    for row, (_, pose) in enumerate(held):
        poses[row] = pose
    count = len(held)
    kept: list[Offer] = []
    for lender, (archived, in_map) in zip(lenders, offers, strict=True):
        tag = foreign_tag(lender.source)
        lender_map = lender.back_end.map
        new: set[int] = set()
        for kf_id, pose in [*((kf.id, kf.pose) for kf in archived),
                            *((k, lender_map.keyframes[k].pose) for k in in_map)]:
            cover = first_cover(pose, poses[:count], views)
            if cover is not None:
                lender.declined[kf_id] = covers[cover]
                continue
            covers.append(kf_id | tag)
            poses[count] = pose
            count += 1
            new.add(kf_id)
        kept.append(([kf for kf in archived if kf.id in new], [k for k in in_map if k in new]))
    return kept


def _seen_only(lenders: list[Lender], offers: list[Offer], in_view: InView) -> list[Offer]:
    """Each lender's ``offers`` (its archived keyframes, its managed map's ids) that
    ``in_view`` says the borrower sees, asked once for every lender's by their points'
    positions (a managed map's keyframe is not copied to be asked about)."""
    positions = [p for lender, (archived, held) in zip(lenders, offers, strict=True)
                 for p in [*(kf.positions for kf in archived),
                           *(lender.back_end.map.positions_of(lender.back_end.map.point_array(k))
                             for k in held)]]
    if not positions:
        return offers
    seen = iter(list(in_view(positions)))
    kept: list[Offer] = []
    for archived, held in offers:
        kept_archived = [kf for kf in archived if next(seen)]
        kept.append((kept_archived, [k for k in held if next(seen)]))
    return kept


def follow_lender_loops(borrower: MapBackEnd, lender: MapBackEnd, source: int,
                        followed: int) -> tuple[int, tuple[FollowedLoop, ...]]:
    """The loops the lender (source map ``source``) applied since the first ``followed`` of
    them, applied to the borrower's copies of its keyframes and to its own keyframes tied to
    them (:meth:`MapBackEnd.follow`, from the borrower's next map version on);
    (how many of the lender's loops the borrower has followed now, what each moved)."""
    tag = foreign_tag(source)
    moves = tuple(borrower.follow(loop, tag)
                  for loop in lender.loops_since(followed))
    return lender.loops_applied, moves


def adopt_lent(borrower: MapBackEnd, keyframes: list[ArchivedKeyFrame], source: int,
               lent: set[int], slot: int, points: MapPoints | None = None,
               offered: dict[int, int] | None = None) -> int:
    """Another map's ``keyframes`` (of source map ``source``, in the borrower's frame) welded
    to the borrower's points (``points``, as they are now; None: read here) and adopted into
    its archive (:meth:`MapBackEnd.adopt`) at ``slot`` — or at the slot each was first
    ``offered`` at (taken out of it) — their ids added to ``lent``: its restores bring them
    in where its device heads, and it tracks on keyframes only the other device uploaded.
    How many."""
    if not keyframes:
        return 0
    # the borrower's points are read once for the batch: welding changes none of them
    points = points or MapPoints.every(borrower.map)
    since = offered if offered is not None else {}
    borrower.adopt(welded(kf, source, borrower.map, borrower.camera,
                          min(since.pop(kf.id, slot), slot), points=points)
                   for kf in keyframes)
    lent.update(kf.id for kf in keyframes)
    return len(keyframes)
