"""The edge's compute budget: over its share of a core the edge trims its local
bundle adjustment step by step, below 60 % of it it restores it, one step per half window;
without a budget nothing changes; a core told to skip bundle adjustment finishes its slots
without one."""

from __future__ import annotations

import itertools

import numpy as np

from edge_mapper.compute_governor import (
    LEVELS,
    NO_NEW_SEARCH,
    ComputeGovernor,
    levels_within,
)
from edge_mapper.edge_core import EdgeMapperCore
from twinslam.policies.rules import make_rule_policy


def _drive(governor: ComputeGovernor, load: float, start: float, seconds: float
           ) -> list[int]:
    """``load`` of a core spent in 0.5 s slots from ``start`` on; the level after each."""
    levels = []
    for k in range(int(seconds / 0.5)):
        now = start + 0.5 * (k + 1)
        governor.charge(0.5 * load, now)
        governor.step(now)
        levels.append(governor.level)
    return levels


def test_over_budget_the_bundle_adjustment_shrinks_and_comes_back_when_the_load_falls() -> None:
    governor = ComputeGovernor(0.8, window_s=4.0)
    heavy = _drive(governor, 1.2, 0.0, 20.0)
    assert heavy[0] == 0 and heavy[-1] == len(LEVELS) - 1          # down to no BA
    assert all(b - a in (0, 1) for a, b in itertools.pairwise(heavy))
    changes = [i for i in range(1, len(heavy)) if heavy[i] != heavy[i - 1]]
    assert all(b - a >= 4 for a, b in itertools.pairwise(changes))   # 2 s apart
    light = _drive(governor, 0.3, 20.0, 20.0)
    assert light[-1] == 0                                            # all the way back
    steady = _drive(governor, 0.6, 40.0, 20.0)                       # between 0.48 and 0.8
    assert set(steady) == {0}


def test_without_a_budget_nothing_changes() -> None:
    assert set(_drive(ComputeGovernor(0.0), 5.0, 0.0, 30.0)) == {0}


def test_a_core_without_bundle_adjustment_still_finishes_its_slots() -> None:
    core = EdgeMapperCore(make_rule_policy("lff"))
    for kf in range(3):
        core.map.add_keyframe(kf, np.eye(4))
    core.set_bundle_adjustment(0, 0)
    out = core.finish_slot(0)
    assert out.bundle_adjustment is None and out.version == 1
    core.set_bundle_adjustment(*(LEVELS[0].window, LEVELS[0].points))
    assert core.back_end.config.ba_window == 5 and core.back_end.config.ba_points == 120


def test_a_budget_never_turns_on_an_adjustment_the_edge_was_told_not_to_run() -> None:
    """An edge started without local bundle adjustment (ba_window 0, the default device) has
    one level, none, however its load goes; one started with 3 keyframes trims from 3."""
    assert [level.window for level in levels_within(0, 120)] == [0]
    governor = ComputeGovernor(0.8, window_s=4.0, levels=levels_within(0, 120))
    assert set(_drive(governor, 1.2, 0.0, 20.0)) | set(_drive(governor, 0.1, 20.0, 20.0)) == {0}
    assert [level.window for level in levels_within(3, 60)] == [3, 1, 0]


def test_an_edge_that_closes_loops_pauses_its_loop_search_last_and_resumes_it_first() -> None:
    """Past no bundle adjustment an edge that closes loops or merges maps starts no new
    search (the default edge has no adjustment to trim: the pause is its one step), and takes
    the searches back first when the load falls; an edge that does neither has no such
    step."""
    assert levels_within(0, 120, searches=True) == (LEVELS[-1], NO_NEW_SEARCH)
    assert [(level.window, level.searches) for level in levels_within(3, 60, searches=True)] \
        == [(3, True), (1, True), (0, True), (0, False)]
    assert all(level.searches for level in levels_within(3, 60))
    assert NO_NEW_SEARCH.describe() == \
        "no local bundle adjustment, no new loop search or place look"
    governor = ComputeGovernor(0.8, window_s=4.0, levels=levels_within(0, 120, True))
    heavy = _drive(governor, 1.2, 0.0, 20.0)
    assert heavy[0] == 0 and heavy[-1] == 1
    assert not governor.levels[governor.level].searches
    assert _drive(governor, 0.3, 20.0, 20.0)[-1] == 0 and governor.levels[0].searches
