"""Splitting one edge's keyframe budget between devices: every allocator hands out
exactly V_total with at least the minimum each, refuses a budget too small for the devices,
and gives more to the device its signal says needs more; the value curves read covisibility
as the device's tracking rule does."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twinslam.allocation.allocators import (
    BudgetError,
    DeviceDemand,
    allocate,
    jain_index,
    split_by_value,
    split_equal,
    split_proportional,
)
from twinslam.allocation.budget_value import budget_value, expected_uploads


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 12), st.integers(1, 6), st.integers(0, 300), st.data())
def test_every_allocator_hands_out_the_whole_budget_with_the_minimum_each(
        n: int, minimum: int, spare: int, data: st.DataObject) -> None:
    total = n * minimum + spare
    novelty = data.draw(st.lists(st.floats(0, 1), min_size=n, max_size=n))
    curves = [np.sort(np.asarray(data.draw(st.lists(st.floats(0, 1), min_size=1,
                                                        max_size=40)))) for _ in range(n)]
    demands = [DeviceDemand(f"ar{i}", i, novelty[i], curves[i]) for i in range(n)]
    for name in ("equal", "motion", "twin"):
        for fairness in (0.0, 1.0):
            shares = allocate(name, total, demands, minimum, fairness)
            assert sum(shares) == total and min(shares) >= minimum, (name, shares)


def test_a_budget_below_the_devices_minimum_is_refused_with_the_reason() -> None:
    with pytest.raises(BudgetError, match="V_total 14 is below 3 devices x 5 keyframes"):
        allocate("equal", 14, [DeviceDemand("a"), DeviceDemand("b"), DeviceDemand("c")], 5)
    with pytest.raises(ValueError, match="unknown allocator 'fifo'"):
        allocate("fifo", 30, [DeviceDemand("a")], 5)
    with pytest.raises(ValueError, match="needs a value curve for b"):
        allocate("twin", 30, [DeviceDemand("a", value=np.ones(3)), DeviceDemand("b")], 5)


def test_equal_and_motion_split_as_their_names_say() -> None:
    assert split_equal(45, [3, 20, 10], 5) == [15, 15, 15]
    assert split_equal(46, [3, 20, 10], 5) == [15, 16, 15]     # the remainder to the fullest
    assert split_proportional(40, [0.1, 0.3, 0.0], 5) == [11, 24, 5]
    assert split_proportional(40, [0.0, 0.0], 5) == [20, 20]   # no signal: equal


def test_value_goes_where_it_gains_most_and_fairness_evens_it_out() -> None:
    # device 0 saturates at 10 keyframes, device 1 keeps gaining until 40
    saturating = np.minimum(np.arange(41) / 10, 1.0)
    slow = np.arange(41) / 40
    shares = split_by_value(50, [saturating, slow], 5)
    assert shares == [10, 40]
    # a curve that rises only after a plateau is reached through its envelope
    late = np.r_[np.zeros(20), np.ones(21)]
    assert split_by_value(30, [slow[:31] * 0.2, late], 5) == [10, 20]
    # proportional fairness lifts the device that is worse off
    low = 0.3 * np.minimum(np.arange(41) / 20, 1.0)
    high = np.minimum(np.arange(41) / 20, 1.0)
    utilitarian = split_by_value(30, [low, high], 5)
    fair = split_by_value(30, [low, high], 5, fairness=1.0)
    assert fair[0] >= utilitarian[0]


def test_jains_index() -> None:
    assert jain_index([0.5, 0.5, 0.5]) == pytest.approx(1.0)
    assert jain_index([1.0, 0.0, 0.0, 0.0]) == pytest.approx(0.25)
    assert jain_index([0.0, 0.0]) == 1.0 and np.isnan(jain_index([]))


def test_a_budget_is_worth_the_frames_its_old_keyframes_let_the_device_track() -> None:
    """Frames sharing points with keyframes as the tracking rule counts them: a frame is
    tracked once the kept keyframes hold ``min_shared`` of its points, the most covisible
    keyframes are kept first, and the expected uploads take their place in the budget."""
    near = np.arange(0, 100)            # a keyframe the frames see well
    far = np.arange(1000, 1100)         # one they do not see at all
    half = np.arange(50, 80)            # one that shares 30 points with each frame
    frames = [np.arange(0, 60), np.arange(10, 70), np.arange(20, 80)]
    value = budget_value([far, half, near], frames, 0.0, 35, 4)
    # budget 1 holds `near` (most covisible): all three frames share >= 35 points with it;
    # the curve ends where the keyframes do (flat beyond)
    assert value.tolist() == [0.0, 1.0, 1.0, 1.0]
    value = budget_value([far, half], frames, 0.0, 35, 3)
    assert value.tolist() == [0.0, 0.0, 0.0]                   # `half` gives 10-30 points
    # two expected uploads come first: the old keyframe `near` needs a budget of three
    value = budget_value([far, near], frames, 2.0, 35, 4)
    assert value.tolist() == [0.0, 0.0, 0.0, 1.0, 1.0]
    assert budget_value([near], [], 0.0, 35, 2).tolist() == [0.0, 0.0]


def test_expected_uploads_follow_theorem_ones_count() -> None:
    # 40 Mbit/s uploads 4 frames a slot, 80 uploads 8 (alpha 5 Mbit, D_req 0.5 s)
    assert expected_uploads([0.25, 0.75], [40.0, 80.0], 5.0, 0.5, 60) == pytest.approx(7.0)
    assert expected_uploads([1.0, 0.0], [0.0, 80.0], 5.0, 0.5, 60) == 0.0   # an outage
    with pytest.raises(ValueError):
        expected_uploads([1.0], [40.0, 80.0], 5.0, 0.5, 60)


def test_a_cells_capacity_is_split_by_weight_and_no_device_gets_more_than_its_link() -> None:
    from twinslam.allocation.allocators import split_capacity

    assert split_capacity(100.0, [40.0, 40.0], [1.0, 3.0]) == [40.0, 40.0]   # room for all
    assert split_capacity(60.0, [40.0, 40.0], [1.0, 3.0]) == pytest.approx([20.0, 40.0])
    # the capped device's leftover goes to the others in their proportions
    assert split_capacity(90.0, [10.0, 80.0, 80.0], [2.0, 1.0, 1.0]) == pytest.approx(
        [10.0, 40.0, 40.0])
    assert split_capacity(30.0, [40.0, 40.0, 40.0], [0.0, 0.0, 0.0]) == pytest.approx(
        [10.0, 10.0, 10.0])


@settings(max_examples=200, deadline=None)
@given(st.floats(0, 500), st.lists(st.tuples(st.floats(0, 100), st.floats(0, 5)),
                                   min_size=1, max_size=12))
def test_a_split_never_exceeds_the_cell_or_a_link_and_leaves_nothing_unused(
        capacity: float, devices: list[tuple[float, float]]) -> None:
    from twinslam.allocation.allocators import split_capacity

    links, weights = [d[0] for d in devices], [d[1] for d in devices]
    shares = split_capacity(capacity, links, weights)
    assert all(-1e-9 <= s <= link + 1e-9 for s, link in zip(shares, links, strict=True))
    assert sum(shares) <= capacity + 1e-6 or sum(shares) == pytest.approx(sum(links))
    assert sum(shares) == pytest.approx(min(capacity, sum(links)), abs=1e-6)
