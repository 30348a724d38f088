"""The edge keeps the objects that outlived a full collection out of the next ones: a full
collection then visits only what came since, garbage made later is still freed, and a frozen
object that became garbage is freed once the frozen objects are handed back."""

from __future__ import annotations

import gc
import weakref

from twinslam.node_runtime.long_lived_objects import (
    keep_survivors_out,
    release_frozen,
    stop_keeping_survivors_out,
)


class _Node:
    """An object in a reference cycle with itself (as a link whose callbacks refer back)."""

    def __init__(self) -> None:
        self.me = self


def test_survivors_of_a_full_collection_are_frozen_and_garbage_is_still_freed() -> None:
    visited: list[int] = []

    def count(phase: str, info: dict[str, int]) -> None:
        if phase == "start" and info["generation"] == 2:
            visited.append(len(gc.get_objects()))

    try:
        keep_survivors_out()
        keep_survivors_out()                        # once installed, installed once
        long_lived = [_Node() for _ in range(20_000)]
        gc.collect()
        assert gc.get_freeze_count() >= 20_000      # the survivors, the 20 000 among them
        gc.callbacks.append(count)
        fresh = _Node()
        dropped = weakref.ref(fresh)
        del fresh
        gc.collect()
        assert dropped() is None                    # garbage made since: freed
        assert visited[-1] < 20_000                 # and the long-lived objects not visited

        survivor = weakref.ref(long_lived[0])
        del long_lived                              # frozen cycles that became garbage
        gc.collect()
        assert survivor() is not None               # ... stay while frozen
        release_frozen()
        gc.collect()
        assert survivor() is None                   # ... and go once handed back
        assert gc.get_freeze_count() > 0            # the survivors frozen again
    finally:
        if count in gc.callbacks:
            gc.callbacks.remove(count)
        stop_keeping_survivors_out()
    assert gc.get_freeze_count() == 0
