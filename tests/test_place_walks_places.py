"""``bench.place_walks`` over several places: a device whose map joined a device of another
place is named a false merge; devices of one place, merged or each its own root, are not.
And its devices' orders of the walk."""

from __future__ import annotations

import argparse
from types import SimpleNamespace
from typing import Any

import pytest

from bench.place_walks import PlaceWalk, _orders, false_merges


def _device(name: str, place: int) -> PlaceWalk:
    walk: Any = SimpleNamespace(name=name)
    return PlaceWalk(walk, 0, place)


def test_a_map_that_joined_another_places_device_is_a_false_merge() -> None:
    # ar1, ar3 walk the kitchen (place 0), ar2, ar4 the corridor (place 1)
    devices = [_device("ar1", 0), _device("ar2", 1), _device("ar3", 0), _device("ar4", 1)]
    # ar3 joined ar1's place, ar4 ar2's: each its own place's
    assert false_merges(devices, {"ar1": "ar1", "ar2": "ar2", "ar3": "ar1", "ar4": "ar2"}) == []
    # ar4 joined ar1's map: a corridor map in the kitchen's frame
    assert false_merges(devices, {"ar1": "ar1", "ar2": "ar2", "ar3": "ar1",
                                  "ar4": "ar1"}) == ["ar4"]
    # ar2's whole place moved into the kitchen's: both corridor devices named
    assert false_merges(devices, {"ar1": "ar1", "ar2": "ar1", "ar3": "ar1",
                                  "ar4": "ar1"}) == ["ar2", "ar4"]


def test_devices_that_never_merge_are_no_false_merges() -> None:
    devices = [_device("ar1", 0), _device("ar2", 1)]
    assert false_merges(devices, {"ar1": "", "ar2": ""}) == []


def test_each_device_plays_its_order_of_the_list_and_an_unknown_order_is_refused() -> None:
    """``--order forward,backward`` walks the corridor from its two ends (device k plays
    order k mod N); a misspelt order is refused before anything runs, naming the orders."""
    assert _orders("forward,backward") == ("forward", "backward")
    assert _orders("backward_forward") == ("backward_forward",)
    with pytest.raises(argparse.ArgumentTypeError, match=r"'sideways'.*orders: forward"):
        _orders("forward,sideways")
