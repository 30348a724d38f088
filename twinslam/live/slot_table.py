"""A live run slot by slot, as a CSV a user opens in a spreadsheet or pandas: which policy
decided each slot and what the edge's map was after it.

The edge's policy can change during a run (``ros2 param set /edge_mapper policy pu``), and a
learned policy falls back to a rule while the twin is silent; the ``policy`` column is what
decided each slot (``UploadRequest.policy``, ``MapStats.policy`` when the request was missed),
so a run's numbers can be split where its policy changed.
"""

from __future__ import annotations

import math
from pathlib import Path

from twinslam.live.run_log import RunLog
from twinslam.reporting import write_csv

#: one row a slot, in slot order
SLOT_COLUMNS = ["slot", "policy", "rate_mbps", "requested", "evicted", "uploads",
                "map_size", "keyframe_budget", "map_points", "archived_keyframes",
                "restored_keyframes",
                "uncertainty", "mean_uncertainty", "tracked_uncertainty", "lost_share",
                "optimisation_ms", "slot_processing_ms", "slot_latency_ms"]


def slot_policies(record: RunLog) -> dict[int, str]:
    """slot → the policy that decided it, for every slot the monitor heard of."""
    decided = {slot: str(m.policy) for slot, m in record.stats.items()}
    decided.update({slot: str(r.policy) for slot, r in record.requests.items()})
    return dict(sorted(decided.items()))


def slot_rows(record: RunLog) -> list[list[object]]:
    """The rows of :data:`SLOT_COLUMNS`; a cell the monitor did not hear is empty."""
    rows: list[list[object]] = []
    for slot, policy in slot_policies(record).items():
        request, stats = record.requests.get(slot), record.stats.get(slot)
        decision: list[object] = ([round(float(request.rate_mbps), 3),
                                   len(request.upload_frame_ids), len(request.evict_frame_ids)]
                                  if request is not None else ["", "", ""])
        after: list[object] = (
            [int(stats.uploads), int(stats.map_size), int(stats.keyframe_budget),
             int(stats.map_points), int(stats.archived_keyframes),
             int(stats.restored_keyframes),
             *(_cell(float(v)) for v in (stats.uncertainty, stats.mean_uncertainty,
                                         stats.tracked_uncertainty)),
             round(float(stats.lost_share), 4), round(float(stats.optimisation_ms), 1),
             round(float(stats.slot_processing_ms), 1), round(float(stats.slot_latency_ms), 1)]
            if stats is not None else [""] * 12)
        rows.append([slot, policy, *decision, *after])
    return rows


def _cell(value: float) -> object:
    """A float as the CSV shows it: ``inf`` (a disconnected map) and ``nan`` spelled out."""
    return round(value, 3) if math.isfinite(value) else str(value)


def write_slot_table(record: RunLog, path: Path) -> None:
    write_csv(path, SLOT_COLUMNS, slot_rows(record))
