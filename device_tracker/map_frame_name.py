"""The frame a device's poses are published in: its own map frame, or the frame of the place
its map joined.

A device names its map frame itself (``map_frame``: its first camera, ``ar2/map`` in a
fleet), and its edge names the same frame in the header of every map update it sends
(``DEVICE/map`` for an edge of several devices). When the edge merges the device's map into
another device's place (``merge_maps``), the map update that carries the merge's motion is in
that place's frame (``ar1/map``), and so is every pose the device tracks on it from then on:
its ``device/pose``, ``device/path`` and REP 105's ``map → odom`` on ``/tf`` must say so, or
a viewer (RViz, Foxglove) shows a device of a shared place where its old frame was, and the
anchors the place shares apart from it.

The edge's name for the device's own frame is the first one its map updates carry: that frame
is published under the device's own ``map_frame`` (a device and an edge named apart keep the
device's name). Any other frame an update carries is published under that name. The name
follows the map version each pose was tracked on, not the newest update: a frame tracked on
the map before the merge is in the frame before the merge.
"""

from __future__ import annotations

#: map versions whose frame is remembered (a pose is published within a slot or two of the
#: map it was tracked on)
VERSIONS_KEPT = 16


class MapFrameName:
    """Which frame name each map version's poses go out in."""

    def __init__(self, own: str) -> None:
        self.own = own                  #: the device's ``map_frame``
        self.edge_own = ""              #: the edge's name for it: its first update's frame
        self._by_version: dict[int, str] = {}

    def applied(self, version: int, frame_id: str) -> None:
        """The map update of ``version`` (its header's ``frame_id``) is the map tracked on
        from now on."""
        if not frame_id:
            return
        if not self.edge_own:
            self.edge_own = frame_id
        self._by_version[version] = self.own if frame_id == self.edge_own else frame_id
        for old in sorted(self._by_version)[:-VERSIONS_KEPT]:
            self._by_version.pop(old, None)

    def of(self, version: int) -> str:
        """The frame poses tracked on map ``version`` are in: the frame of the newest map
        applied at or before it (the device's own before any)."""
        # one copy taken at once: the map updates' callback edits the table meanwhile
        held = [(v, name) for v, name in list(self._by_version.items()) if v <= version]
        return max(held)[1] if held else self.own
