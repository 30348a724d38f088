"""What the device's log says about one tracked frame, without DDS.

A user watching a device wants the moments its tracking changes — lost, relocalised, a
relocalisation refused, a pose refused as an impossible motion, a map of its own started or
handed back to the edge's — once each,
not a line a frame. The node writes these lines to its logger; tests read them here.
"""

from __future__ import annotations

from dataclasses import dataclass

from device_tracker.device_core import FrameResult


@dataclass(frozen=True)
class LogLine:
    text: str
    warning: bool = False              #: a warning, else information
    throttled: bool = False            #: at most one a second (a state that repeats a frame)


def frame_log_lines(result: FrameResult) -> list[LogLine]:
    """The lines ``result`` is worth, in the order they happened."""
    frame = result.record.frame_id
    lines = []
    if result.implausible:
        lines.append(LogLine(f"frame {frame}: pose refused, {result.implausible} (an impossible "
                             "motion)", warning=True, throttled=True))
    if result.lost_now:
        lines.append(LogLine(f"frame {frame}: tracking lost; relocalising against the local map",
                             warning=True))
    elif result.recovered:
        lines.append(LogLine(f"frame {frame}: relocalised"))
    elif result.refused:
        lines.append(LogLine(f"frame {frame}: relocalisation refused: {result.refused}",
                             throttled=True))
    if result.own_map == "started":
        lines.append(LogLine(f"frame {frame}: lost too long; tracking with points of its own "
                             "from depth until the edge's map explains the view again",
                             warning=True))
    elif result.own_map == "ended":
        lines.append(LogLine(f"frame {frame}: tracked by the edge's map again; the device's "
                             "own points go"))
    return lines
