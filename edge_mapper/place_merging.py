"""The maps of an edge's devices merged where one device walks into another's place (the
edge node's ``merge_maps``), beside the slots.

An edge serving several devices keeps a map per device, each in the frame of its device's
first camera. After each slot of a device whose map joined no other yet, the keyframes it
integrated that slot are looked for in the whole map (archive and managed map) of one other
device — the one whose keyframes its last look's scored most like in the process's keyframe
database (below) — on the process's loop-closing worker,
queued behind the loop jobs (:data:`~twinslam.slam.back_end.loop_closing.SHARED_WORKER`): place
recognition in another device's map took 17-30 ms a look (``bench.place_walks`` over three
places), half to two thirds of the looking device's own slot work, after every slot of a
device whose place no other shares — 3-4 ms since its search is screened and stops at too few
votes (:class:`~twinslam.slam.back_end.map_merging.MergeFinder`). On a thread of their own the
looks took the slots' interpreter and cores beside the loop closer's worker, outside what the
edge's ``loop_worker_niceness``, ``loop_worker_share`` and ``loop_worker_yields`` bound; on
the one worker the edge's background work is one queue under those bounds, and a look waits,
before each of its keyframes, while a slot callback runs (as a loop job does before each
query). A merge the joining map's next keyframes confirmed
(:class:`~twinslam.slam.back_end.map_merging.MergeFinder`) is applied at the device's next
slot end, before its map update goes out
(:meth:`~edge_mapper.edge_core.EdgeMapperCore.align`): that update carries the new frame
correction, and the device's poses are in the place's frame from then on. From then on, at
each slot end of either, each map adopts the other's own keyframes it has not adopted yet
that its device's camera sees from where it heads (``lend_in_view``; the rest wait until it
heads where they are), welded to its points, into its archive (:meth:`PlaceMerging.lend_all`):
restores bring them in where the device heads, and each device tracks on keyframes only the
other uploaded. The copies adopted before move with each loop the lender closed since
(:func:`~twinslam.slam.back_end.map_merging.follow_lender_loops`): lent before and after a
loop, they would stand a loop's correction apart. And each map's loop closer may close loops
with the copies of its place's other devices (``loops_across_devices``,
:func:`~twinslam.slam.back_end.loop_closing.loop_across`): where a device comes to a place
another mapped first, its walk, drifted since the merge, bends towards that device's
keyframes.

The devices in one frame are a place: its first device in the edge's order (the root) and
the devices that joined it; the place's frame is its root's first camera's, and its
archives recognise places under its root's vocabulary, learned once a place, not once a
device (:meth:`~twinslam.slam.back_end.place_words.PlaceWords.share`). Each root looks in
the maps of the devices of every other place: in the one its keyframes score highest in the
process's keyframe database (:mod:`~twinslam.slam.back_end.keyframe_database`, every
device's uploaded keyframes as bags of words; scored on the worker, by the look before), and
in turn among those scoring near it; in turn among all of them while the database has no
words yet (its first ~40 keyframes, of any devices), and one look in eight whatever it ranks
(EXPLORE_EVERY). Taken in turn only, a newcomer's
keyframes met its place's map once in as many looks as there were other maps, and merged
later the more devices the edge served. Where it finds its keyframes, the
two places become one in the earlier root's frame — the later place's devices, all of them,
moved by the merge's motion (or its inverse, when the later place's map was the one looked
in) at once, between slots: a device walking ahead of an earlier one never comes to a place
that device mapped before it, yet the earlier one comes to its places, and two places each
other devices joined already still merge. Each device's next map update carries its motion.
A look that finished after either map's frame changed (a loop closed, a merge) is dropped,
its alignment measured against poses a map no longer has.

A device whose looks find no candidate place — no keyframe of the map it looked in passed the
screen and PnP — may look less often (``look_backoff_slots`` above 1, the edge's
``merge_look_backoff_slots``): after each such look it waits twice as many slots as before,
up to that many, and looks every slot again once a look finds a candidate or the edge serves
another device's map. Twelve devices each alone in its place on one core cost the edge's loop
worker twice the CPU with ``merge_maps`` (the looks and the database's filing, ~14 ms a
device-slot); a device that walks into a mapped place then merges up to that many slots
less one later.

Each device's checkpoint records its place — the root whose frame its map is in, and how many
of each lender's loops its copies followed (:mod:`edge_mapper.place_membership`) — and the
copies' tags are functions of the lenders' names: an edge restarted from its checkpoints, or a
standby taking them over, serves each device in the place it left (:meth:`PlaceMerging.serve`)
— no look, no keyframe adopted twice, no loop followed twice — whatever order its devices come
back in. A device whose root is not served (yet) is a place of its own again and looks.

With ``join`` (the edge's ``merge_join``) a merge makes the two places one map instead, and
nothing is lent (:meth:`PlaceMerging._join`): the map of the place that moves — a place of
one device where the other holds several, else the later root's — joins the other's back
end whole, its devices' keyframes under their tags
(:func:`~twinslam.slam.back_end.place_joining.join_into_place`), and each of its devices
goes on in the place's map (:meth:`~edge_mapper.edge_core.EdgeMapperCore.join_place`).
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future, wait
from dataclasses import dataclass

import numpy as np

from edge_mapper.edge_core import EdgeMapperCore, set_aside
from edge_mapper.place_membership import PlaceMembership, run_after, source_of
from twinslam.slam.back_end.foreign_keyframes import foreign_tag, is_foreign, source_id, tag_of
from twinslam.slam.back_end.keyframe_archive import KeyFrameArchive
from twinslam.slam.back_end.keyframe_database import KeyFrameDatabase, WeightedWords
from twinslam.slam.back_end.loop_closing import SHARED_WORKER, LoopQuery, SharedWorker
from twinslam.slam.back_end.map_back_end import FollowedLoop
from twinslam.slam.back_end.map_merging import (
    MERGE_MIN_INLIERS,
    Lender,
    Lending,
    MapMerge,
    MergeFinder,
    lend_from,
)
from twinslam.slam.back_end.place_index import KeptPlaceIndex
from twinslam.slam.back_end.view_coverage import CoverageBounds
from twinslam.slam.keyframe import KeyFramePayload
from twinslam.thread_names import name_this_thread
from twinslam.thread_priority import lower_this_thread

#: newest integrated keyframes of a slot looked for (a slot integrates a few; a look costs
#: place recognition for each)
LOOK_QUERIES = 3
#: uploads queued for the keyframe database past which a device that makes no look files
#: them on the worker (the looks file them otherwise)
FILE_QUEUED = 64
#: one look in this many goes to the other maps in turn, whatever the keyframe database
#: ranks first: a place its words misjudge (one that scores below another that looks alike)
#: is still looked for, at worst this many times the other maps' count of looks apart
EXPLORE_EVERY = 8


@dataclass(frozen=True)
class MergeEvent:
    """A device's map moved into another device's frame."""

    device: str                      #: the joining device
    place: str                       #: the device whose frame it joined
    merge: MapMerge
    look_ms: float                   #: the worker's time on the look that confirmed it
    #: the device of its place whose map met the other place's ("": its own), when the
    #: device moved along with its place
    via: str = ""


@dataclass(frozen=True)
class _Look:
    """One look's answer, with what it was made against: the looking device's keyframes in
    the ``other`` device's whole map."""

    other: str
    merge: MapMerge | None
    frame: np.ndarray                #: the looking map's frame correction when it started
    ms: float
    error: str = ""                  #: why the look failed ("": it did not)
    #: what its last keyframe found, or why it found nothing (a merge: "")
    found: str = ""
    #: the other map's frame correction when it started (a reverse look's: its map moves)
    other_frame: np.ndarray | None = None
    #: the maps the keyframe database ranked worth the next look, best first (empty: no
    #: ranking, the next look takes the other maps in turn)
    ranked: tuple[str, ...] = ()
    #: a keyframe of the look found a place in the other map (passed the screen and a
    #: loop's PnP inliers), confirmed or not, on the merge's inliers or fewer
    candidate: bool = False


class PlaceMerging:
    """Looks for each unmerged device's place in the maps of the devices before it, and
    moves its map into the first one's frame it finds (``cores``: the edge's devices and
    their cores, in the order they are served)."""

    def __init__(self, cores: Callable[[], Mapping[str, EdgeMapperCore]],
                 background: bool = True, min_inliers: int = MERGE_MIN_INLIERS,
                 lend_in_view: bool = True, unseen_slots: int = 0,
                 lent_views: CoverageBounds | None = None,
                 worker: SharedWorker = SHARED_WORKER,
                 database: KeyFrameDatabase | None = None, look_backoff_slots: int = 1,
                 join: bool = False) -> None:
        self.cores = cores
        #: a merge makes one map of the two places (:meth:`_join`: the place's bundle
        #: adjustment and loops run once, a device's uploads are every device's keyframes at
        #: once); False: each device keeps its map and borrows the others' keyframes as
        #: copies (:meth:`lend_all`)
        self.join = join
        #: joined device → its core, whose record leaves the place's back end with it
        #: (:meth:`forget`: the edge no longer serves it, so :attr:`cores` has it no more)
        self._joined_cores: dict[str, EdgeMapperCore] = {}
        #: with :attr:`join`, the root of a place its first device handed over → the source
        #: of the device gone, whose tag the place's untagged ids take where it joins another
        #: place (:meth:`_join`)
        self._untagged: dict[str, int] = {}
        #: what the edge's log should say of its places since the last :meth:`notices`
        self._notices: list[str] = []
        #: every device's uploaded keyframes as bags of words: which maps a look goes to
        self.database = database if database is not None else KeyFrameDatabase()
        #: with the looks on the worker, the database's words are learned on a thread of
        #: their own (:meth:`_learn_beside`), never by a look's ranking
        self.database.learn_in_scoring = not background
        self._learning: threading.Thread | None = None
        #: device → the maps its last look's keyframes scored highest in, best first
        self._ranked: dict[str, tuple[str, ...]] = {}
        #: device → its looks that took the other maps in turn (unranked, or every
        #: EXPLORE_EVERY-th)
        self._explored: dict[str, int] = {}
        #: the database's queue being filed on the worker (:meth:`_file_beside`)
        self._filing: Future[None] | None = None
        #: looks on ``worker`` (the process's loop-closing worker by default), else in the
        #: caller (the benches: answers that do not depend on the threads' timing)
        self.background = background
        self.worker = worker
        #: the PnP inliers each detection of a merge needs (the edge's merge_min_inliers)
        self.min_inliers = min_inliers
        #: lend a keyframe only once the borrowing device heads where it sees it (the edge's
        #: lend_in_view; else every keyframe as soon as its device made it)
        self.lend_in_view = lend_in_view
        #: with lend_in_view, the slots a copy stays in a borrower's archive while its device
        #: neither holds nor sees it, before it goes back to its lender (the edge's
        #: lent_unseen_slots; 0: kept)
        self.unseen_slots = unseen_slots
        #: a view lent once: a keyframe of another device whose view a copy the borrower holds
        #: covers within these bounds is not lent (the edge's lent_view_m, lent_view_deg;
        #: None: every keyframe of the place is lent)
        self.lent_views = lent_views
        if look_backoff_slots < 1:
            raise ValueError(f"the looks' backoff is 1 slot or more, not {look_backoff_slots}")
        #: the most slots between two looks of a device whose looks found no candidate
        #: (1: a look after every slot)
        self.look_backoff_slots = look_backoff_slots
        #: device → the slot its running look started at
        self._look_started: dict[str, int] = {}
        #: device → (slots between its looks now, the first slot it may look at again)
        self._look_gap: dict[str, tuple[int, int]] = {}
        #: device → the maps it could look in at its looks so far
        self._looked_among: dict[str, set[str]] = {}
        #: joined device → the device whose frame it is in
        self.joined: dict[str, str] = {}
        self._finders: dict[tuple[str, str], MergeFinder] = {}
        self._queries: dict[str, list[LoopQuery]] = {}
        self._turn: dict[str, int] = {}
        self._running: dict[str, Future[_Look]] = {}
        self.look_ms: list[float] = []          #: every finished look's worker time
        #: (borrower, lender) → the lender's keyframes the borrower's map adopted (by the
        #: lender's ids)
        self._lent: dict[tuple[str, str], set[int]] = {}
        #: (borrower, lender) → how many of the lender's loops the borrower's copies followed
        self._followed: dict[tuple[str, str], int] = {}
        #: (borrower, lender) → the lender's keyframes not lent yet, held back out of the
        #: borrower's view, by the borrower's slot each was first offered at
        self._offered: dict[tuple[str, str], dict[int, int]] = {}
        #: (borrower, lender) → the lender's keyframes lent, by the borrower's last slot that
        #: held or saw the copy
        self._seen: dict[tuple[str, str], dict[int, int]] = {}
        #: (borrower, lender) → the lender's keyframes not lent for a copy the borrower holds
        #: of their view already, by that copy's id (with :attr:`lent_views`)
        self._declined: dict[tuple[str, str], dict[int, int]] = {}
        #: device → the root its restored checkpoint named (:meth:`serve`), until it is placed
        self._recorded: dict[str, str] = {}
        #: device → the run of its map (:func:`~edge_mapper.place_membership.source_of`):
        #: one more each time it is forgotten, a reclaimed device's or a restarted one's
        self._runs: dict[str, int] = {}
        #: (borrower, lender) pairs refused because another device's copies carry the
        #: lender's tag (:func:`~edge_mapper.place_membership.source_of`), each said once
        self._clashes: set[tuple[str, str]] = set()
        self._clashes_new: list[str] = []
        #: device → the place index of its whole map the looks into it keep from one look to
        #: the next (one look at a time: the looks' one worker), edited as its map changes
        #: instead of built for every look (:mod:`~twinslam.slam.back_end.place_index`)
        self._look_indexes: dict[str, KeptPlaceIndex] = {}
        #: new looks start (False: the edge's compute budget paused them, as it pauses the
        #: loop search: a look running goes on, and each device's newest keyframes look
        #: when they resume)
        self.looking = True
        #: why looks failed since the last :meth:`failures` (the link logs them)
        self._failed: list[str] = []
        #: device → looks finished without a merge, and what the last one found
        self.unmerged_looks: dict[str, tuple[int, str]] = {}
        #: device → the merge that moved its map while another device's look was taken, for
        #: its own slot end to tell (its link logs it and names the new frame)
        self._moved: dict[str, MergeEvent] = {}
        #: device → the merges its own look made that moved other devices' maps into its
        #: place (it stayed), for its slot end to tell: a moved device whose walk has ended
        #: has no slot end of its own to tell it
        self._brought: dict[str, list[MergeEvent]] = {}

    def serve(self, device: str) -> str:
        """``device`` is served (its core made, restored from its checkpoint if it had one):
        its checkpoint's place taken back — it rejoins its root if that device is served and
        a root, and the served devices that named ``device`` as theirs and joined no place
        since rejoin it — and the core's checkpoints record its place from now on. What was
        restored, in words ("": nothing)."""
        core = self.cores()[device]
        core.saved_with = lambda: self.membership(device).arrays()
        self.database.forget(device)         # a new map, or the restored one's own keyframes
        if not core.back_end.restored_from_file:
            # a new map: past the runs of the maps set aside before it, in this process or
            # (its file moved aside) in an edge that ran before
            self._runs[device] = max(self._runs.get(device, 0),
                                     run_after(set_aside(core.checkpoint))
                                     if core.checkpoint is not None else 0)
            return ""
        # in capture order (the archive holds them in the order they left the slice): the
        # database sums a map's consecutive keyframes into one row, neighbours with neighbours
        for kf_id, descriptors in sorted(core.back_end.store.descriptors(),
                                         key=lambda kept: kept[0]):
            if not is_foreign(kf_id):
                self.database.add(device, kf_id, descriptors)
        record = PlaceMembership.read(core.back_end.extra)
        self._runs[device] = record.run
        for lender, count in record.followed.items():
            self._followed[(device, lender)] = count
        for lender, offered in record.offered.items():
            self._offered[(device, lender)] = dict(offered)
        if record.root and record.root != device:
            self._recorded[device] = record.root
        placed = self._rejoin()
        if device in self.joined:
            return f"back in {self.joined[device]}'s place"
        if record.root and record.root != device:
            return (f"its place's root {record.root} is not served: a place of its own until "
                    f"{record.root} is, or a look finds the place again")
        back = [d for d in placed if d != device]
        return f"{', '.join(back)} back in its place" if back else ""

    def _rejoin(self) -> list[str]:
        """The devices restored with a root that is served and a root now, joined to it;
        which ones."""
        cores = self.cores()
        placed = []
        for device, root in list(self._recorded.items()):
            if device not in cores:
                del self._recorded[device]
            elif device in self.joined or any(r == device for r in self.joined.values()):
                del self._recorded[device]            # it is in a place of its own making
            elif root in cores and root not in self.joined:
                del self._recorded[device]
                self.joined[device] = root
                cores[device].archive.words.share(cores[root].archive.words)
                self._queries.pop(device, None)
                placed.append(device)
        return placed

    def membership(self, device: str) -> PlaceMembership:
        """``device``'s place as its checkpoint records it."""
        root = self.joined.get(device) or self._recorded.get(device, "")
        return PlaceMembership(root,
                               {lender: n for (borrower, lender), n in self._followed.items()
                                if borrower == device}, self._runs.get(device, 0),
                               {lender: dict(kfs) for (borrower, lender), kfs
                                in self._offered.items() if borrower == device and kfs})

    def source(self, device: str) -> int:
        """The source index the copies of ``device``'s current map carry."""
        return source_of(device, self._runs.get(device, 0))

    def keyframe(self, device: str, data: KeyFramePayload) -> None:
        """A keyframe of ``device`` the edge accepted: filed in the keyframe database (a look
        may come to its map), and its features kept for the device's next look."""
        self.database.add(device, data.frame_id, data.descriptors)
        if device in self.joined:
            return
        queries = self._queries.setdefault(device, [])
        queries.append(LoopQuery.of(data))
        del queries[:-LOOK_QUERIES]

    def root(self, device: str) -> str:
        """The first device of ``device``'s place (itself, when it joined none)."""
        return self.joined.get(device, device)

    def place_of(self, device: str) -> list[str]:
        """Every device in ``device``'s frame: its place's root first, then the devices that
        joined it, in the edge's order."""
        root = self.root(device)
        return [d for d in self.cores() if d == root or self.joined.get(d) == root]

    def others(self, device: str) -> list[str]:
        """The devices whose maps ``device`` looks in: those of the other places, while
        ``device`` is the root of its own (a device that joined another looks no more)."""
        if device not in self.cores() or device in self.joined:
            return []
        return [d for d in self.cores() if self.root(d) != device]

    def before_slot_end(self, device: str, slot: int
                        ) -> tuple[MergeEvent | None, int, list[FollowedLoop]]:
        """Before ``device``'s slot end: a finished look's merge applied (:meth:`take`), and
        the keyframes of the other devices of its place that its map has not adopted yet
        adopted (:meth:`lend_all`); (the merge that moved its map, or None; keyframes adopted;
        the other devices' loops that moved its own keyframes, or would have)."""
        merged = self.take(device)
        if self.join:                    # one map: every keyframe of the place is its own
            return merged, 0, []
        lendings = self.lend_all(device, [d for d in self.place_of(device) if d != device],
                                 slot)
        return merged, sum(lending.adopted for lending in lendings), \
            [move for lending in lendings for move in lending.moves if move.reached_own]

    def lend_all(self, borrower: str, lenders: list[str], slot: int) -> list[Lending]:
        """Each lender's own keyframes (its archive and map; not those it adopted itself)
        that the borrower's map has not adopted yet — the maps in one frame — welded to the
        borrower's points and adopted into its archive (:meth:`MapBackEnd.adopt`): its
        restores bring them in where its device heads, and it tracks on keyframes only the
        other devices uploaded; first, each lender's loops since the last lending move the
        copies and the borrower's keyframes tied to them. With :attr:`lend_in_view`, only
        the keyframes the borrower's camera sees from where it heads
        (:meth:`EdgeMapperCore.in_coming_view`): the others wait until it heads where they
        are. One round for all ``lenders``
        (:func:`lend_from`: the borrower's points read once for all their keyframes); each
        lender's lending, in their order (one the edge no longer serves lends nothing)."""
        cores = self.cores()
        serving = [lender for lender in lenders if lender in cores and borrower in cores
                   and not self._tag_clash(borrower, lender)]
        rounds: list[Lender] = []
        for lender in serving:
            pair = (borrower, lender)
            source = self.source(lender)
            # a first lending's copies carry every loop the lender applied so far
            followed = self._followed.setdefault(pair, cores[lender].back_end.loops_applied)
            if pair not in self._lent:      # a restarted edge: the copies the map holds
                self._lent[pair] = _copies_of(cores[borrower], source)
            rounds.append(Lender(cores[lender].back_end, source, self._lent[pair], followed,
                                 self._offered.setdefault(pair, {}),
                                 self._seen.setdefault(pair, {}),
                                 self._declined.setdefault(pair, {})))
        in_view = cores[borrower].in_coming_view if self.lend_in_view else None
        done = dict(zip(serving, lend_from(cores[borrower].back_end, rounds, slot, in_view,
                                           self.unseen_slots, self.lent_views),
                        strict=True)) if serving else {}
        # the borrower's loops may close with the copies of its place's other devices (those
        # it adopted a while before: MapBackEnd._across)
        if borrower in cores:
            cores[borrower].back_end.loop_across = frozenset(
                foreign_tag(self.source(lender)) for lender in serving)
        for lender, lending in done.items():
            self._followed[(borrower, lender)] = lending.followed
        return [done.get(lender) or Lending(self._followed.get((borrower, lender), 0), 0)
                for lender in lenders]

    def declined(self, borrower: str) -> int:
        """The place's keyframes not lent to ``borrower``'s map now, each for a copy it holds
        of their view already (:attr:`lent_views`)."""
        return sum(len(declined) for (b, _), declined in self._declined.items()
                   if b == borrower)

    def _tag_clash(self, borrower: str, lender: str) -> bool:
        """Whether another device — served, or one that lent to ``borrower`` before — tags
        its copies as ``lender`` does: the borrower could not tell their keyframes and points
        apart, so ``lender`` lends it nothing (said once, :meth:`tag_clashes`)."""
        tag = self.source(lender)
        others = set(self.cores()) | {d for (b, d) in self._followed if b == borrower}
        clash = sorted(d for d in others if d != lender and self.source(d) == tag)
        if clash and (borrower, lender) not in self._clashes:
            self._clashes.add((borrower, lender))
            self._clashes_new.append(f"{lender}'s keyframes are not lent to this map: their "
                                     f"tag is {clash[0]}'s too (rename one of the devices)")
        return bool(clash)

    def tag_clashes(self) -> list[str]:
        """Lendings refused for a shared tag since the last call (once each pair)."""
        said, self._clashes_new = self._clashes_new, []
        return said

    def take(self, device: str) -> MergeEvent | None:
        """Before ``device``'s slot end: the merge that moved its map since its last slot end
        (None: none). Its own finished look's merge is made here — its place and the other
        one become one place in the earlier root's frame, the later place's devices moved at
        once — unless it found none or a map's frame changed since the look started."""
        moved = self._moved.pop(device, None)
        running = self._running.get(device)
        if running is None or not running.done():
            return moved
        del self._running[device]
        look = running.result()
        self.look_ms.append(look.ms)
        self._ranked[device] = look.ranked
        self._back_off(device, look.candidate)
        if look.error:
            self._failed.append(f"looking for {look.other}'s place failed: {look.error}")
        if look.merge is None:
            count, _ = self.unmerged_looks.get(device, (0, ""))
            self.unmerged_looks[device] = (count + 1, f"in {look.other}'s map: {look.found}; "
                                           f"{_next_looks(look.ranked)}")
            return moved
        cores = self.cores()
        if device not in cores or look.other not in cores or device in self.joined or \
                self.root(look.other) == device or look.other_frame is None or not (
                    np.allclose(cores[device].frame_correction, look.frame, atol=1e-12) and
                    np.allclose(cores[look.other].frame_correction, look.other_frame,
                                atol=1e-12)):
            return moved
        self._merge_places(device, look.other, look.merge, look.ms)
        return self._moved.pop(device, None) or moved

    def _back_off(self, device: str, candidate: bool) -> None:
        """After ``device``'s look: the slots until its next one — twice the last gap where
        it found no candidate place (up to :attr:`look_backoff_slots`), one where it did."""
        started = self._look_started.pop(device, 0)
        gap, _ = self._look_gap.get(device, (1, 0))
        gap = 1 if candidate else min(2 * gap, self.look_backoff_slots)
        self._look_gap[device] = (gap, started + gap)

    def _merge_places(self, device: str, other: str, merge: MapMerge, ms: float) -> None:
        """``device``'s place (it is the root) and ``other``'s made one: ``merge`` carries
        ``device``'s frame into ``other``'s; the place whose root comes later in the edge's
        order moves — by ``merge`` or its inverse — every device of it into the other root's
        frame, each told at its next slot end. With :attr:`join` the two maps become one
        (:meth:`_join`)."""
        if self.join:
            self._join(device, other, merge, ms)
            return
        order = list(self.cores())
        root = self.root(other)
        if order.index(root) < order.index(device):
            stay, met, movers, motion = root, device, self.place_of(device), merge
        else:
            stay, met, movers, motion = device, other, self.place_of(root), merge.inverse()
        cores = self.cores()
        for m in movers:
            cores[m].align(motion.alignment)
            self.joined[m] = stay
            # the place's devices recognise places under one vocabulary (its root's)
            cores[m].archive.words.share(cores[stay].archive.words)
            self._queries.pop(m, None)
            self._moved[m] = MergeEvent(m, stay, motion, ms, "" if m == met else met)
            if device not in movers:
                self._brought.setdefault(device, []).append(self._moved[m])

    def _join(self, device: str, other: str, merge: MapMerge, ms: float) -> None:
        """``device``'s place (it is the root) and ``other``'s made one map — ``merge``
        carries ``device``'s frame into ``other``'s: one place's map joins the other's
        (:meth:`EdgeMapperCore.join_place`), its first device's keyframes under that
        device's tag, its other devices' under theirs, by ``merge`` or its inverse. A place
        of one device joins a place of several (the fewer keyframes move); otherwise the
        place whose root the edge served later joins, as :meth:`_merge_places` moves it."""
        cores = self.cores()
        root = self.root(other)
        mine, theirs = self.place_of(device), self.place_of(root)
        order = list(cores)
        if (len(mine) == 1) != (len(theirs) == 1):
            mine_moves = len(mine) == 1
        else:
            mine_moves = order.index(root) < order.index(device)
        if mine_moves:
            stay, mover, motion, movers = root, device, merge, mine
        else:
            stay, mover, motion, movers = device, root, merge.inverse(), theirs
        # the moving map's untagged ids are its first device's, which may have handed the
        # place over to ``mover`` (:meth:`_leave_joined_place`)
        untagged = self._untagged.get(mover, self.source(mover))
        try:
            cores[mover].join_place(cores[stay], foreign_tag(untagged), motion.alignment,
                                    [cores[d] for d in movers if d != mover])
        except ValueError as exc:
            self._failed.append(f"{mover}'s map could not join {stay}'s place: {exc}")
            return
        self._untagged.pop(mover, None)
        # the device of the moving place whose map met the other place's
        met = device if mine_moves else other
        for m in movers:
            self.joined[m] = stay
            self._joined_cores[m] = cores[m]
            self._queries.pop(m, None)
            self._moved[m] = MergeEvent(m, stay, motion, ms, "" if m == met else met)
            if not mine_moves:
                self._brought.setdefault(device, []).append(self._moved[m])

    def brought(self, device: str) -> list[MergeEvent]:
        """The merges ``device``'s own looks made since the last call that moved other
        devices' maps into its place's frame, ``device`` staying where it is (once each)."""
        return self._brought.pop(device, [])

    def look(self, device: str, slot: int) -> None:
        """After ``device``'s slot end: its newest keyframes looked for in the whole map of a
        device of another place (:meth:`others`), on the worker (nothing while its last look
        runs, or with nothing new). The map is the one its last look's keyframes scored
        highest in the keyframe database, or in turn those within its candidate share; the
        others in turn while nothing is ranked (the database's words not learned yet), and
        every EXPLORE_EVERY-th look whatever is ranked. The look ranks its own keyframes for
        the next one (on the worker: the words' time is not the slot's). None starts while
        :attr:`looking` is off."""
        self._learn_beside()
        queries = self._queries.get(device)
        others = self.others(device)
        if not self.looking or not queries or not others or device in self._running or \
                self._backing_off(device, slot, others):
            self._file_beside()
            return
        turn = self._turn.get(device, 0)
        self._turn[device] = turn + 1
        ranked = [d for d in self._ranked.get(device, ()) if d in others]
        if ranked and (turn + 1) % EXPLORE_EVERY:
            place = ranked[turn % len(ranked)]
        else:                             # in turn: no ranking yet, or the odd look out
            explored = self._explored.get(device, 0)
            self._explored[device] = explored + 1
            place = others[explored % len(others)]
        cores = self.cores()
        other, joining = cores[place], cores[device]
        if not other.map.keyframes or not joining.camera.known:
            return
        snapshot = other.back_end.store.snapshot(
            slot, self._look_indexes.setdefault(place, KeptPlaceIndex()))
        poses = joining.back_end.keyframe_poses()
        finder = self._finders.setdefault((device, place),
                                          MergeFinder(min_inliers=self.min_inliers))
        job = (place, finder, snapshot, tuple(queries), poses, joining.k.copy(),
               joining.frame_correction.copy(), other.frame_correction.copy())
        self._queries[device] = []
        self._look_started[device] = slot
        self._looked_among.setdefault(device, set()).update(others)
        rank = functools.partial(self.database.candidates_of, device,
                                 [query.keyframe for query in queries], others)
        # the other place's first device's camera took its keyframes that name none (in a
        # joined place, not ``place``'s own where it joined it): the merge's depths read by it
        look = functools.partial(_look, other_intrinsics=other.back_end.k.copy())
        if self.background:
            self._running[device] = self.worker.submit(look, *job, self.worker.wait_for_slots,
                                                       rank, after_loops=True)
        else:
            done: Future[_Look] = Future()
            done.set_result(look(*job, rank=rank))
            self._running[device] = done

    def _backing_off(self, device: str, slot: int, others: list[str]) -> bool:
        """Whether ``device`` waits at ``slot`` for its next look (its last ones found no
        candidate, :meth:`_back_off`); not once the edge serves a map it had not looked
        among."""
        gap, after = self._look_gap.get(device, (1, 0))
        if gap == 1:
            return False
        if not set(others) <= self._looked_among.get(device, set()):
            self._look_gap[device] = (1, 0)            # a map it never looked among
            return False
        return slot < after

    def _file_beside(self) -> None:
        """The keyframe database's queue filed on the worker once it is long (no look filed
        it: every device in one place, or one device alone), one filing at a time."""
        if self.database.queued() < FILE_QUEUED or (
                self._filing is not None and not self._filing.done()):
            return
        if self.background:
            self._filing = self.worker.submit(self.database.file, after_loops=True)
        else:
            self.database.file()

    def _learn_beside(self) -> None:
        """The keyframe database's words learned once enough uploads' descriptors wait for
        them: on a thread of their own beside the looks, which rank in turn until the next
        scoring takes the words (here in the caller, without the looks' worker). Learned by
        a look's ranking instead, they held that look up — 3.0 s on one core, 5.7 s on a
        host its devices kept busy — and a device coming to a mapped place merged 8–10 slots
        late, uploading as if alone meanwhile (docs/results/shared-map.md, "The words
        learned beside the looks"). One learning a process, at the lowest priority (the
        slots' threads first); one that fails is reported and the looks go on in turn."""
        if self._learning is not None or not self.database.can_learn():
            return
        if not self.background:
            self.database.file()
            return
        sample = self.database.learning_sample()
        words = self.database.word_count

        def learn() -> None:
            # at the lowest priority: the k-means runs outside the interpreter's lock, and on
            # a host the slots fill it took their cores in the walk's first slots
            lower_this_thread(19)
            name_this_thread()                  # "place-words" in top -H and ps -L
            try:
                self.database.offer_words(WeightedWords.learn(sample, words))
            except Exception as exc:        # reported with the looks' failures
                self._failed.append(f"learning the keyframe database's words: "
                                    f"{type(exc).__name__}: {exc}")

        self._learning = threading.Thread(target=learn, name="place-words", daemon=True)
        self._learning.start()

    def forget(self, device: str) -> None:
        """A reclaimed device, or one that started again: served again, it starts a map of its
        own that joins anew (the devices that joined its frame stay in it: the first of them
        is their place's root now), and its next map's copies carry a tag of their own — the
        copies of this map that other maps keep are of other keyframes and points than the
        next map's of the same ids."""
        source = self.source(device)
        self._runs[device] = self._runs.get(device, 0) + 1
        if self.join:
            self._leave_joined_place(device, source)
        if device not in self.joined:                  # a root: its place goes on without it
            rest = [d for d in self.place_of(device) if d != device]
            for d in rest:
                self.joined[d] = rest[0]
            if rest:
                del self.joined[rest[0]]
        self.joined.pop(device, None)
        self._moved.pop(device, None)
        self._brought.pop(device, None)
        for pair in [pair for pair in self._lent if device in pair]:
            del self._lent[pair]
            self._followed.pop(pair, None)
        for pair in [pair for pair in self._offered if device in pair]:
            del self._offered[pair]
        for pair in [pair for pair in self._seen if device in pair]:
            del self._seen[pair]
        for pair in [pair for pair in self._declined if device in pair]:
            del self._declined[pair]
        self._queries.pop(device, None)
        self._running.pop(device, None)
        for backoff in (self._look_started, self._look_gap, self._looked_among):
            backoff.pop(device, None)
        self._look_indexes.pop(device, None)
        self._turn.pop(device, None)
        self._ranked.pop(device, None)
        self._explored.pop(device, None)
        self.database.forget(device)
        self._recorded.pop(device, None)
        self._clashes = {pair for pair in self._clashes if device not in pair}
        for pair in [pair for pair in self._finders if device in pair]:
            del self._finders[pair]

    def _leave_joined_place(self, device: str, source: int) -> None:
        """With :attr:`join`, ``device`` (of source ``source``) gone: a device that joined a
        place leaves it (:meth:`EdgeMapperCore.leave_place`: the keyframes only it held go to
        the place's archive); the device that leads a place others joined hands it to the
        next of them in the edge's order (:meth:`EdgeMapperCore.lead_place`), whose core
        runs the place's bundle adjustment and whose looks look for other places from now on
        (:meth:`forget` makes it the place's root); the place's untagged ids stay the gone
        device's, under its tag where the place joins another (said once)."""
        core = self._joined_cores.pop(device, None)
        if core is not None:
            core.leave_place()
            return
        rest = [d for d in self.place_of(device) if d != device]
        if not rest:
            self._untagged.pop(device, None)
            return
        lead = rest[0]
        self._joined_cores.pop(lead, None)
        self.cores()[lead].lead_place()
        self._untagged[lead] = self._untagged.pop(device, source)
        self._notices.append(f"{device}, the device that led a joined place, is no longer "
                             f"served: {lead} leads its place from now on (its bundle "
                             "adjustment, its looks for other places)")

    def notices(self) -> list[str]:
        """What the edge's log should say of its places since the last call (once each)."""
        said, self._notices = self._notices, []
        return said

    def failures(self) -> list[str]:
        """Why looks failed since the last call (once each): the edge goes on unmerged."""
        failed, self._failed = self._failed, []
        return failed

    def close(self) -> None:
        """Wait for the looks on the worker (and a filing of the keyframe database's queue):
        a running one finishes, one not started yet is dropped (its map is closing). The
        words' learning is not waited for: nothing will score with its words, and at the
        lowest priority on a loaded host it may take minutes — a stopping edge waited for it
        past the 5 s a node is given to stop. Its thread is a daemon: the process's exit
        ends it."""
        looks = [look for look in self._running.values() if not look.cancel()]
        filing = [self._filing] if self._filing is not None and not self._filing.cancel() \
            else []
        self._running.clear()
        with self.worker.outside_slot_work():
            wait(looks)
            wait(filing)


def _next_looks(ranked: tuple[str, ...]) -> str:
    """Where the next looks go, in words, for the edge's log of a device not merged yet."""
    if not ranked:
        return "the next in the other maps in turn (no ranking: the keyframe database has no " \
            "words yet)"
    maps = " or ".join(f"{d}'s" for d in ranked)
    in_turn = " in turn" if len(ranked) > 1 else ""
    return f"the next in {maps} map{in_turn}, whose keyframes its own are most like"


def _copies_of(core: EdgeMapperCore, source: int) -> set[int]:
    """The lender ids of the copies of source ``source``'s keyframes ``core``'s map and
    archive hold: what a restarted edge's lendings need not adopt again."""
    tag = foreign_tag(source)
    return {source_id(k) for k in core.back_end.store.ids() if tag_of(k) == tag}


def _look(place: str, finder: MergeFinder, other: KeyFrameArchive,
          queries: tuple[LoopQuery, ...], poses: dict[int, np.ndarray], intrinsics: np.ndarray,
          frame: np.ndarray, other_frame: np.ndarray,
          pause: Callable[[], None] = lambda: None,
          rank: Callable[[], list[str]] = list,
          other_intrinsics: np.ndarray | None = None) -> _Look:
    """The looking map's ``queries`` (oldest first) offered to ``finder`` against the other
    device's whole map ``other``, until one confirms a merge; a failure reported in the
    answer, never raised (a look that fails must not take the edge's slots down with it).
    ``pause`` is called before each query: the worker waits there for the slots' work
    (:meth:`~twinslam.slam.back_end.loop_closing.SharedWorker.wait_for_slots`); the time
    it waits is not the look's. First, ``rank`` scores the queries in the keyframe database:
    the maps the next look goes to (its time is the look's); a ranking that fails is reported
    and the look searches on (the next one takes the maps in turn). ``other_intrinsics``:
    the other device's camera, which took its keyframes (None: the looking device's)."""
    spent = 0.0
    merge = None
    ranked: tuple[str, ...] = ()
    seen_before = finder.sightings
    unranked = ""
    pause()
    started = time.perf_counter()
    try:
        ranked = tuple(rank())
    except Exception as exc:            # reported with the look's answer
        unranked = f"ranking the maps: {type(exc).__name__}: {exc}"
    spent += time.perf_counter() - started
    try:
        for query in sorted(queries, key=lambda q: q.keyframe):
            if query.keyframe in poses:
                pause()
                started = time.perf_counter()
                try:
                    merge = finder.offer(other, query, poses, intrinsics, other_intrinsics)
                finally:
                    spent += time.perf_counter() - started
                if merge is not None:
                    break
    except Exception as exc:            # reported by the device's next slot end, with the
        failed = f"{type(exc).__name__}: {exc}"              # ranking's failure if it failed
        return _Look(place, None, frame, spent * 1e3,
                     f"{failed}; {unranked}" if unranked else failed,
                     other_frame=other_frame, ranked=ranked)
    last = finder.last
    found = "" if merge is not None or last is None else (
        f"keyframe {last.old} on {last.inliers} inliers, not confirmed yet" if last.found
        else last.reason)
    return _Look(place, merge, frame, spent * 1e3, unranked, found=found,
                 other_frame=other_frame, ranked=ranked,
                 candidate=finder.sightings > seen_before)
