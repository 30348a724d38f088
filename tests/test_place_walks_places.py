"""``bench.place_walks`` over several places: a device whose map joined a device of another
place is named a false merge; devices of one place, merged or each its own root, are not.
And its devices' orders of the walk."""

from __future__ import annotations

import argparse
from types import SimpleNamespace
from typing import Any

import pytest

from bench.place_walks import PlaceWalk, _orders, false_merges
from twinslam.slot_protocol import default_device


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


def test_interleaved_devices_get_a_slot_as_long_and_play_no_frame_twice() -> None:
    """``--interleave N``: a device playing one frame in N gets 1/N of the camera's rate and of
    a slot's frames (a slot lasts as long), what it was given stands, a slot that does not
    split N ways is refused naming the fix; and the phases the run gives its devices play
    disjoint frames of the walk."""
    from bench.in_process import interleaved_device
    from twinslam.sequence_player.playback import Playback, phase_for
    from twinslam.slot_protocol import table1

    slot = default_device.SLOT_FRAMES
    assert interleaved_device({}, 1) == {}
    third = interleaved_device({}, 3)
    assert third == {"slot_frames": slot // 3, "frame_rate_hz": table1.FRAME_RATE_HZ / 3}
    assert third["slot_frames"] / third["frame_rate_hz"] == slot / table1.FRAME_RATE_HZ
    assert interleaved_device({"slot_frames": 8}, 4)["slot_frames"] == 8
    with pytest.raises(ValueError, match="slot_frames=N"):
        interleaved_device({}, 7)
    played = [{n for n in range(100) if Playback(every=5, phase=phase_for(k, 0, 5)).plays(n)}
              for k in range(4)]
    assert all(len(p) == 20 for p in played)
    assert all(not (a & b) for i, a in enumerate(played) for b in played[i + 1:])


@pytest.mark.parametrize(("argv", "says"), [
    (["../shared/data/7scenes-1000", "--own-walks"], "--own-walks: a walk of each device's own"),
    (["--interleave", "7"], f"--interleave 7: a slot of {default_device.SLOT_FRAMES} frames "
     "does not split 7 ways"),
    (["--interleave", "0"], "--interleave: 1 (every frame) or more")])
def test_walks_no_device_can_play_are_refused_before_anything_runs(
        argv: list[str], says: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A dataset is one recorded walk (no walk of each device's own there), and a slot that
    does not split among the interleaved devices' frames: refused with the reason, exit 2."""
    from bench import place_walks

    monkeypatch.setattr("sys.argv", ["place_walks", *argv])
    with pytest.raises(SystemExit) as exited:
        place_walks.main()
    assert exited.value.code == 2
    assert says in capsys.readouterr().err


def test_each_device_sees_through_a_camera_of_its_focal_length() -> None:
    """``--focals 525,450``: device k's walk is seen by a camera of the k-th focal length
    (mod their count), its spec naming it; a focal length that is no number is refused, and
    a dataset's walk cannot take one."""
    from bench.place_walks import _focals
    from twinslam.sequences.opening import open_sequence, with_focal

    focals = _focals("525,450")
    assert focals == (525.0, 450.0)
    specs = [with_focal(f"synthetic-corridor:4:{k}", focals[k % 2]) for k in range(3)]
    assert [open_sequence(s).intrinsics[0, 0] for s in specs] == [525.0, 450.0, 525.0]
    assert with_focal("synthetic:4:0", None) == "synthetic:4:0"
    with pytest.raises(argparse.ArgumentTypeError, match="focal lengths in pixels"):
        _focals("525,wide")
    assert with_focal("synthetic:4:0:600", 450.0) == "synthetic:4:0:450"
    with pytest.raises(ValueError, match="synthetic world's walk"):
        with_focal("../shared/data/7scenes-1000", 450.0)
