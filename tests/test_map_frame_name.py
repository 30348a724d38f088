"""The frame a device's poses go out in: its own until its map joins another place, that
place's frame from the first pose tracked on the merged map, its own again if it leaves."""

from __future__ import annotations

from device_tracker.map_frame_name import VERSIONS_KEPT, MapFrameName


def test_poses_follow_the_frame_of_the_map_they_were_tracked_on() -> None:
    names = MapFrameName("ar2_map")          # the device names its frame apart from the edge
    assert names.of(0) == "ar2_map"          # no map yet
    names.applied(1, "ar2/map")              # the edge's name for the device's own frame
    names.applied(2, "ar2/map")
    assert names.of(2) == "ar2_map"
    names.applied(5, "ar1/map")              # the update that carries the merge
    assert names.of(4) == "ar2_map"          # tracked before it: still the frame it left
    assert [names.of(v) for v in (5, 6)] == ["ar1/map", "ar1/map"]
    names.applied(9, "ar2/map")              # the place left (its root forgotten)
    assert names.of(9) == "ar2_map" and names.of(7) == "ar1/map"
    names.applied(10, "")                    # an update with no frame named changes nothing
    assert names.of(10) == "ar2_map"


def test_only_the_newest_versions_are_remembered() -> None:
    names = MapFrameName("map")
    names.applied(1, "map")
    for version in range(2, 2 + 3 * VERSIONS_KEPT):
        names.applied(version, "ar1/map")
    assert len(names._by_version) == VERSIONS_KEPT
    assert names.of(1 + 3 * VERSIONS_KEPT) == "ar1/map"
