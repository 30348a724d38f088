"""Keep the objects that outlived a full garbage collection out of the next ones.

An edge's maps are hundreds of thousands of Python objects that live as long as the run (a
``MapPoint`` and its observer set a point: ~40 000 for one device on the 7-Scenes walk).
CPython's cyclic collector visits every tracked object at each full (generation 2)
collection, so the pause grows with the fleet: 80 ms rising to 190 ms on one edge process
serving 12 emulated devices (``bench.edge_scaling``, timed by ``gc.callbacks``), every
device's slot stalled meanwhile — and about four times that at fifty devices. Those
collections found nothing to free: the maps hold no reference cycles, and reference counting
frees them when they go.

Right after a full collection generations 0 and 1 are empty and every object left has
survived it; :func:`keep_survivors_out` freezes them then (``gc.freeze``: the permanent
generation, never visited again), so each full collection visits only what was made since
the last one — 5 to 17 ms in the same run. An object frozen that later becomes part of a cycle
nobody reaches stays in memory: where a node drops much at once (an edge reclaiming a
device's link and map, whose callbacks refer back to it), :func:`release_frozen` hands every
frozen object back to the collector, and the next full collection frees what is garbage and
freezes the rest again.
"""

from __future__ import annotations

import gc
from typing import Any


def _freeze_survivors(phase: str, info: dict[str, Any]) -> None:
    """A ``gc.callbacks`` entry: after a full collection, freeze what survived it."""
    if phase == "stop" and info.get("generation") == 2:
        gc.freeze()


def keep_survivors_out() -> None:
    """From now on, every full collection freezes its survivors (once installed, a second
    call changes nothing)."""
    if _freeze_survivors not in gc.callbacks:
        gc.callbacks.append(_freeze_survivors)


def release_frozen() -> None:
    """Hand every frozen object back to the collector: the next full collection visits them
    once (freeing the garbage among them) and freezes the survivors again."""
    gc.unfreeze()


def stop_keeping_survivors_out() -> None:
    """Undo :func:`keep_survivors_out` and :func:`release_frozen` (a test, a node that
    stops)."""
    while _freeze_survivors in gc.callbacks:
        gc.callbacks.remove(_freeze_survivors)
    gc.unfreeze()
