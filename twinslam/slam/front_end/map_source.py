"""Where the device's poses come from (``map_source``, docs/architecture.md §1 step 1).

* ``edge`` — the paper's device: only the points of the edge's last map update (a start-up map
  from the first frame's depth before the first update). What the edge keeps decides whether
  a frame is tracked; this is the mode the simulator models and evaluations are judged in.
* ``edge+local`` — an Edge-SLAM style device: the edge's map plus the device's own points of
  its last few slots; it tracks on where the edge's map no longer reaches.
"""

from __future__ import annotations

from twinslam.slot_protocol import default_device

EDGE = "edge"
EDGE_LOCAL = "edge+local"
MAP_SOURCES = (EDGE, EDGE_LOCAL)
#: the product's one default — the device node's parameter, the bundled parameter file,
#: ``twinslam launch`` and ``twinslam evaluate`` alike: the Edge-SLAM style device, measured
#: best on every uplink family (:mod:`twinslam.slot_protocol.default_device`); the paper's
#: device (``edge``, the mode the simulator models) is ``config/paper-table1.yaml``'s
DEFAULT_MAP_SOURCE = default_device.MAP_SOURCE


def check_map_source(value: object) -> str | None:
    """None for a known map source, else the reason it is refused."""
    if value in MAP_SOURCES:
        return None
    return (f"unknown map source {value!r}: must be {EDGE} (track only against the edge's "
            f"map, the paper's device) or {EDGE_LOCAL} (the edge's map plus the device's own "
            "recent points)")
