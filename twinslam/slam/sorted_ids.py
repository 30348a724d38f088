"""Keys looked up in a sorted array of ids: where each stands and whether it is there.

The edge asks this of thousands of keys at once — a slot's frames' point keys against the
map's points (the plan's lost-frame rule, its covisibility with the frames), the points a
keyframe holds against the copies another device lent — and a sorted search answers all of
them in one pass, where a set or ``np.isin`` sorts the ids again each time.
"""

from __future__ import annotations

import numpy as np


def find_sorted(sorted_ids: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``keys``, its index in ``sorted_ids`` (ascending, without repeats) and
    whether it is there; an index is meaningful only where it is found."""
    at = np.searchsorted(sorted_ids, keys)
    found = at < len(sorted_ids)
    found[found] = sorted_ids[at[found]] == keys[found]
    return at, found
