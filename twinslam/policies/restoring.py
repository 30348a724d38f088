"""Archived keyframes brought back into the map where the device is: ``restore:POLICY``.

The paper's edge forgets what it evicts, so a device walking back into an evicted place fails
there whatever the policy chose. An edge with an archive can bring keyframes back over the
downlink (no uplink time): the live edge does it after the policy's decision, from the view
at the device's extrapolated poses (:mod:`edge_mapper.restores`). This module is the same
step in terms every policy sees — frames and their covisibility weights — so the simulator
can score it, a planner can plan it and the clairvoyant reference can do it with the future
known:

an archived keyframe comes back when it shares at least :data:`MIN_VIEW_POINTS` map points
with a frame of the *view*; once the map is full it takes the place of the map keyframe that
shares least with the view (never one uploaded this slot), and only when it shares more than
:data:`REPLACE_RATIO` times what that one shares; a restore that would cut the map in two is
skipped (a disconnected map has no finite uncertainty, its parts no common frame).

What the view is decides what kind of policy it is: ``restore:POLICY`` looks at the next
slot's frames where the camera's motion across this slot leads (in the simulator
:meth:`~twinslam.policies.world_model.MapManagementEnv.coming_view`, causal, as the live edge's
extrapolated poses; the slot's newest tracked frames where no world predicts them), the
reference at the next slot's true frames, ``mpc`` at the frames its world model predicts.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import replace
from typing import Any, Protocol, runtime_checkable

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.protocol import MapPolicy, WorldPlanner
from twinslam.uncertainty.map_uncertainty import map_uncertainty

RESTORE_PREFIX = "restore"
#: an archived keyframe is worth bringing back only if a frame of the view shares this many
#: of its points (the device's rule asks for 30 map points a frame: fewer would not keep a
#: frame tracked on their own)
MIN_VIEW_POINTS = 30
#: and, in a full map, only if it shares more than this many times what the keyframe it
#: replaces shares with the view
REPLACE_RATIO = 2.0
#: the slot's newest tracked frames that stand for where the device is going
VIEW_FRAMES = 3


def victim_for(score: float, scores: Mapping[int, float], keep: Collection[int]) -> int | None:
    """The map keyframe an archived one whose view score is ``score`` replaces in a full map:
    of ``scores`` (each map keyframe's view score) the lowest not in ``keep``; None when none
    may go or the archived one would not see more than :data:`REPLACE_RATIO` times what it
    does — the candidates come best first, so the restores stop there."""
    replaceable = [k for k in scores if k not in keep]
    if not replaceable:
        return None
    victim = min(replaceable, key=lambda k: (scores[k], k))
    return victim if score > REPLACE_RATIO * scores[victim] else None


def choose_restores(candidates: Sequence[tuple[float, int]], map_scores: Mapping[int, float],
                    room: int, limit: int, protected: Collection[int],
                    connected: Callable[[list[int]], bool]) -> tuple[list[int], list[int]]:
    """The restore rule (the module docstring's), in whatever terms a caller scores a view:
    (restored, evicted). ``candidates`` are (view score, archived keyframe) at or above
    :data:`MIN_VIEW_POINTS`, best first; ``map_scores`` each map keyframe's view score (its
    keys are the map); ``room`` the keyframes the map may still add under V_max; ``limit``
    the most to restore; ``protected`` keyframes are never replaced (this slot's uploads);
    ``connected(keyframes)`` whether a map of those keyframes is one covisibility graph (the
    keyframe it would restore comes last among them). The edge calls it with points seen
    from predicted poses (:mod:`edge_mapper.restores`), the simulator with covisibility
    weights (:func:`with_restores`): one rule decides for both."""
    scores = dict(map_scores)
    current = list(scores)
    keep = set(protected)
    restore: list[int] = []
    evict: list[int] = []
    for score, kf in candidates:
        if len(restore) >= limit:
            break
        victim = None
        if room <= 0:
            victim = victim_for(score, scores, keep)
            if victim is None:
                break                    # the others are better still: nothing more to gain
        trial = [k for k in current if k != victim] + [kf]
        if not connected(trial):
            continue
        current, scores[kf] = trial, score
        restore.append(kf)
        keep.add(kf)
        if victim is None:
            room -= 1
        else:
            evict.append(victim)
            del scores[victim]
    return restore, evict


def with_restores(obs: SlotObservation, action: MapAction, view: Sequence[int]) -> MapAction:
    """``action`` with up to ``obs.n_restore`` archived keyframes brought back for ``view``
    (frame instances whose weights ``obs.weights`` knows), and the map keyframes they replace
    added to its evictions (the module docstring's rule); ``action`` itself when nothing of
    the archive is in view."""
    if obs.n_restore <= 0 or not obs.archive or not len(view):
        return action
    view = list(view)
    seen = obs.weight_block(obs.archive, view).max(axis=1)
    candidates = sorted(((float(s), a) for s, a in zip(seen, obs.archive, strict=True)
                         if s >= MIN_VIEW_POINTS), key=lambda sa: (-sa[0], sa[1]))
    if not candidates:
        return action
    current = sorted((set(obs.map_frames) | set(action.upload)) - set(action.evict))
    scores: dict[int, float] = {}
    if current:
        scores = dict(zip(current, obs.weight_block(current, view).max(axis=1).tolist(),
                          strict=True))
    room = (obs.vmax - len(current)) if obs.vmax is not None else obs.n_restore
    restore, evict = choose_restores(
        candidates, scores, room, obs.n_restore, action.upload,
        lambda trial: math.isfinite(map_uncertainty(obs.weight_block(trial, trial))))
    if not restore:
        return action
    return MapAction(list(action.upload), sorted([*action.evict, *evict]), restore)


@runtime_checkable
class ViewPredictor(Protocol):
    """A world that predicts the next slot's frames at the end of a slot (the simulator's
    environment does): (a weights function that knows them, their ids)."""

    def coming_view(self, slot: int) -> tuple[Callable[[list[int], list[int]], Any],
                                              list[int]]: ...


def newest_view(obs: SlotObservation) -> list[int]:
    """The slot's newest tracked frames: where a causal rule assumes the device goes on."""
    return list(obs.candidates[-VIEW_FRAMES:])


class RestoringPolicy:
    """``policy``'s uploads and evictions, then archived keyframes brought back for the
    coming view (:func:`with_restores`): the next slot's frames as the world it is attached
    to predicts them from the camera's motion, else the slot's newest tracked frames. Without
    an archive (the paper's edge) it is ``policy``."""

    def __init__(self, policy: MapPolicy) -> None:
        self.policy = policy
        self.name = f"{RESTORE_PREFIX}:{policy.name}"
        self._world: ViewPredictor | None = None

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed)

    def attach(self, env: Any) -> None:
        """The world whose coming view it restores for; passed on to a wrapped planner
        (``mpc`` imagines its future in ``env``)."""
        self._world = env if isinstance(env, ViewPredictor) else None
        if isinstance(self.policy, WorldPlanner):
            self.policy.attach(env)

    def decide(self, obs: SlotObservation) -> MapAction:
        action = self.policy.decide(obs)
        if obs.n_restore <= 0:
            return action
        if self._world is None:
            return with_restores(obs, action, newest_view(obs))
        weights, coming = self._world.coming_view(obs.slot)
        return with_restores(replace(obs, weights=weights), action, coming)

