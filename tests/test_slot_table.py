"""A run whose policy was changed while it ran (``ros2 param set /edge_mapper policy pu``) says
so: its slot table names the policy that decided each slot, and the run's table row names
both policies instead of the one it was launched with."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
from twinslam_msgs.msg import MapStats, UploadRequest

from msg_schemas import new
from twinslam.live.report import report
from twinslam.live.run_log import RunLog
from twinslam.live.slot_table import SLOT_COLUMNS, write_slot_table


def _record(decided: list[str], missed_request: int | None = None) -> RunLog:
    record = RunLog()
    for slot, policy in enumerate(decided):
        if slot != missed_request:
            record.requests[slot] = new(UploadRequest, slot=slot, policy=policy,
                                        rate_mbps=40.0, upload_frame_ids=np.arange(4),
                                        evict_frame_ids=np.arange(slot % 2))
        record.stats[slot] = new(MapStats, slot=slot, policy=policy, map_size=slot + 1,
                                 uploads=4, uncertainty=math.inf if slot == 0 else -100.0 - slot,
                                 mean_uncertainty=math.nan, lost_share=0.25,
                                 restored_keyframes=slot % 2)
    return record


def test_a_policy_set_during_the_run_is_named_in_the_table_and_per_slot(tmp_path: Path
                                                                        ) -> None:
    record = _record(["lff", "lff", "pu", "pu", "lff"], missed_request=3)
    run = report("lff", record, seconds=10.0, slot_frames=30)
    assert run.decided_by == "lff:3, pu:1"          # slot 3's request was missed
    assert run.label == "lff→pu" and run.row().startswith("lff→pu ")
    write_slot_table(record, tmp_path / "lff.slots.csv")
    with (tmp_path / "lff.slots.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == SLOT_COLUMNS
    assert [r["policy"] for r in rows] == ["lff", "lff", "pu", "pu", "lff"]   # 3 from MapStats
    assert rows[3]["requested"] == "" and rows[2]["requested"] == "4"
    assert rows[1]["evicted"] == "1" and rows[0]["uncertainty"] == "inf"
    assert rows[4]["map_size"] == "5" and rows[4]["mean_uncertainty"] == "nan"
    # the keyframes the edge brought back from its archive: per slot, and summed in the row
    assert [r["restored_keyframes"] for r in rows] == ["0", "1", "0", "1", "0"]
    assert run.restores == 2


def test_a_run_that_kept_its_policy_or_fell_back_keeps_its_label() -> None:
    assert report("pu", _record(["pu"] * 3), 1.0, 30).label == "pu"
    learned = report("mbrl:/tmp/amm.pt", _record(["adapt (fallback)", "mbrl:/tmp/amm.pt"]),
                     1.0, 30)
    assert learned.decided_by == "adapt (fallback):1, mbrl:/tmp/amm.pt:1"
    assert learned.label == "mbrl:amm"
