"""A map that stays one graph: a step after any policy's decision.

A map in pieces — keyframes that share no point with the rest — has no finite uncertainty
(u(G) = +∞, DESIGN §2): every frame of the next slot scores as lost, whatever the device
tracked, and its pieces have no common frame. Two kinds of decision leave one:

* **Uploads that see nothing of the map.** A rule that uploads the slot's newest frames (LFF,
  the default) assumes they overlap the map. Where the camera turns fast they need not: on
  the synthetic corridor, a device turning at the corridor's far end turned 88° between the
  last frames of two slots, and the two keyframes each slot uploaded shared no point with the
  two before.
* **Evictions that take a bridge.** A rule that evicts the keyframes that entered the map
  first may take the one keyframe that ties a later piece to the rest — on the corridor, the
  keyframe that tied two keyframes which had entered the map later to the rest.

:func:`connected_action` leaves a decision alone whenever the map it leaves has no more pieces
than the map it starts from. Otherwise it mends what splits it, keeping Theorem 1's counts
(the uplink's time and V_max stay as planned):

* evictions, in the policy's order and then the map's keyframes in the order they entered it,
  each taken only where it splits nothing (an island may go; a bridge stays);
* uploads, among the slot's tracked frames: the newest that tie to the map by :data:`MIN_TIE`
  shared points (map points, or the device's tracks between two frames of the slot), then the
  newest that tie to the map or a frame chosen so far — in a fast turn a frame from mid-turn
  that sees the map, then the newest frame, which sees that one.

Where the mended decision would leave as many pieces or more, the policy's stands.

Those two keep a map whole; they cannot rejoin one already in pieces, and nothing else does:
a restore from the archive must leave the map's uncertainty finite, so none is taken while
it is not. Measured on four devices walking the corridor (``bench.place_walks
--own-walks``): a device's upload at a turn shared no point with its map and no frame of the
slot tied to it; the piece behind the camera stayed for 23-38 slots, its keyframes evicted
one a slot by Theorem 1's count, every frame counted lost (u = +∞) while the device tracked
them all. So a piece that no tracked frame of :data:`STALE_SLOTS` slots in a row has tied to
(:func:`seen_keyframes`) — the camera has left it — goes whole with the slot's evictions,
beyond Theorem 1's count where it is larger: the map left is what the camera sees, its
uncertainty finite again, and the piece waits in the archive, from which a restore brings
its keyframes back once the camera heads there. The slot's evictions made room; the piece's
size of them counts towards them (the policy's others, as many as the count still asks).
A piece is never dropped while it holds all the map (a device lost, tying to nothing: the
map stays for the edge to relocalise it in), nor one that holds a keyframe that entered the
map within those slots (uploads count as seen).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS

#: shared points that tie a frame to the map (or to a chosen frame) when mending uploads: as
#: many as the device needs to track a frame on a map (the lost-frame rule's MIN_INLIERS);
#: one shared point makes a graph connected, not a keyframe a device can be tracked by
MIN_TIE = MIN_INLIERS

#: slots in a row in which no tracked frame tied to a piece of a map in pieces before it is
#: dropped: one slot looking away (a glance at a wall, a fast turn and back) keeps the map
#: the camera comes back to; two at the default 1 s slots is two seconds of a map in pieces
STALE_SLOTS = 2


def _components(weights: np.ndarray) -> tuple[int, np.ndarray]:
    """(pieces, the piece of each node) of the graph ``weights > 0``, at least one node."""
    # a sparse graph for scipy: handed a dense one, it converts it at twice the cost
    count, label = connected_components(csr_matrix(np.asarray(weights) > 0), directed=False)
    return int(count), label


def pieces(weights: np.ndarray) -> int:
    """How many connected pieces the graph ``weights > 0`` falls into (none for no node)."""
    return _components(weights)[0] if len(weights) else 0


def seen_keyframes(map_weights: np.ndarray, frame_weights: np.ndarray) -> np.ndarray:
    """Which keyframes of a map (``map_weights``: shared points among them) lie in a piece
    that one of the slot's tracked frames ties to (``frame_weights``: a row a frame, a column
    a keyframe) by :data:`MIN_TIE` shared points, as a bool a keyframe."""
    n = len(map_weights)
    if not n:
        return np.zeros(0, dtype=bool)
    _, label = _components(map_weights)
    tied = (np.asarray(frame_weights).reshape(-1, n) >= MIN_TIE).any(axis=0)
    seen: np.ndarray = np.bincount(label, weights=tied)[label] > 0
    return seen


class _Graph:
    """The slot's map keyframes and candidate frames, by id, with their shared counts."""

    def __init__(self, obs: SlotObservation) -> None:
        self.nodes = list(dict.fromkeys([*obs.map_frames, *obs.candidates]))
        self.at = {x: i for i, x in enumerate(self.nodes)}
        self.w = obs.weight_block(self.nodes, self.nodes).astype(np.float64)
        np.fill_diagonal(self.w, 0.0)

    def pieces(self, ids: Sequence[int]) -> int:
        rows = [self.at[x] for x in ids]
        return pieces(self.w[np.ix_(rows, rows)])

    def labels(self, ids: Sequence[int]) -> np.ndarray:
        """The piece each of ``ids`` lies in (labels 0, 1, ...)."""
        rows = [self.at[x] for x in ids]
        return _components(self.w[np.ix_(rows, rows)])[1]

    def tie(self, frame: int, to: Sequence[int]) -> float:
        """The most points ``frame`` shares with one of ``to``."""
        if not to:
            return 0.0
        return float(self.w[self.at[frame], [self.at[x] for x in to]].max())


def connected_action(obs: SlotObservation, action: MapAction,
                     stale: Collection[int] = frozenset()) -> MapAction:
    """``action``, or — where the map it leaves has more pieces than the map it starts from —
    its evictions and uploads mended as the module docstring says (as many of each; restores
    kept as they are); where the map it leaves is in pieces, a piece all of whose keyframes
    are ``stale`` (no tracked frame has tied to their piece for :data:`STALE_SLOTS` slots)
    evicted whole with them."""
    if set(action.upload) & set(action.evict) or not obs.map_frames:
        return action
    graph = _Graph(obs)
    evict = _evictions(graph, obs, action)
    upload = _uploads(graph, obs, action, evict)
    dropped = _stale_pieces(graph, obs, upload, stale)
    if dropped:
        gone = set(dropped)
        rest = [k for k in evict if k not in gone]
        evict = [*dropped, *rest[:max(len(evict) - len(dropped), 0)]]
    if (evict, upload) == (list(action.evict), list(action.upload)):
        return action
    if graph.pieces([*_kept(obs, evict), *upload]) >= graph.pieces(
            [*_kept(obs, action.evict), *action.upload]):
        return action                 # never a mend that leaves as many pieces or more
    return MapAction(upload, evict, list(action.restore))


def _stale_pieces(graph: _Graph, obs: SlotObservation, upload: Sequence[int],
                  stale: Collection[int]) -> list[int]:
    """The keyframes of the pieces of the map with the slot's uploads whose keyframes are all
    ``stale``, oldest entered first; none where nothing else would be left."""
    if not stale:
        return []
    pool = [*obs.map_frames, *(f for f in upload if f not in obs.map_frames)]
    label = graph.labels(pool)
    if label.max(initial=0) == 0:
        return []
    fresh = {int(label[i]) for i, k in enumerate(pool) if k not in stale}
    if not fresh:
        return []
    gone = {k for i, k in enumerate(pool) if int(label[i]) not in fresh}
    return [k for k in obs.entry_order() if k in gone]


def _kept(obs: SlotObservation, evict: Sequence[int]) -> list[int]:
    gone = set(evict)
    return [k for k in obs.map_frames if k not in gone]


def _evictions(graph: _Graph, obs: SlotObservation, action: MapAction) -> list[int]:
    """The policy's evictions, or — where they split the map — as many taken one by one,
    the policy's first, each only where the map (with the uploads) keeps its pieces."""
    evict = list(action.evict)
    if not evict:
        return evict
    floor = graph.pieces([*obs.map_frames, *action.upload])
    if graph.pieces([*_kept(obs, evict), *action.upload]) <= floor:
        return evict
    order = list(dict.fromkeys([*evict, *obs.entry_order()]))
    chosen: list[int] = []
    for k in order:
        if len(chosen) == len(evict):
            break
        trial = [*chosen, k]
        if graph.pieces([*_kept(obs, trial), *action.upload]) <= floor:
            chosen = trial
    if len(chosen) < len(evict):          # no split-free choice: the policy's own
        return evict
    return chosen


def _uploads(graph: _Graph, obs: SlotObservation, action: MapAction, evict: Sequence[int]
             ) -> list[int]:
    """The policy's uploads, or — where they add a piece of their own to the map the
    evictions leave — as many of the newest frames that tie to it."""
    uploads = list(action.upload)
    kept = _kept(obs, evict)
    if not uploads or not kept:
        return uploads
    split = graph.pieces([*kept, *uploads])
    if split <= max(graph.pieces(kept), 1):
        return uploads
    tied = list(kept)
    mended: list[int] = []
    newest_first = list(reversed(obs.candidates))
    while len(mended) < len(uploads):
        found = next((f for f in newest_first
                      if f not in mended and graph.tie(f, tied) >= MIN_TIE), None)
        if found is None:
            break
        mended.append(found)
        tied.append(found)
    if not mended:
        return uploads
    mended += [f for f in reversed(uploads) if f not in mended][:len(uploads) - len(mended)]
    if graph.pieces([*kept, *mended]) >= split:
        return uploads
    return sorted(mended)


def mended_decision(policy: MapAction, mended: MapAction,
                    name: Callable[[int], str] = str) -> str:
    """What :func:`connected_action` changed, in words (the edge's log line); ``name`` names
    a keyframe the evictions list (the edge: another device's copy by its own id)."""
    def listed(ids: Sequence[int]) -> str:
        return "[" + ", ".join(name(k) for k in ids) + "]"

    parts = []
    outcome = ": the map stays one graph"
    if list(policy.upload) != list(mended.upload):
        parts.append(f"uploads {list(mended.upload)} instead of the policy's "
                     f"{list(policy.upload)}, which share no point with the map")
    if len(mended.evict) > len(policy.evict):
        parts.append(f"evicts {listed(sorted(mended.evict))} instead of the policy's "
                     f"{listed(sorted(policy.evict))}: the map was in pieces, and no tracked "
                     f"frame tied to these for {STALE_SLOTS} slots")
        outcome = ": the map keeps the piece the camera is in"
    elif list(policy.evict) != list(mended.evict):
        parts.append(f"evicts {listed(sorted(mended.evict))} instead of the policy's "
                     f"{listed(sorted(policy.evict))}, which would cut the map")
    return "; ".join(parts) + outcome if parts else "as the policy chose"
