"""How long the update loop takes, stage by stage: from the last frame of slot k to the first
frame the device tracks with the map that slot produced.

Past a slot period the device tracks the next slot on an older map (the lag the calibration
measures); this says where the time goes. Each stage is read off what the run's monitor heard
and when (:attr:`~twinslam.live.run_log.RunLog.heard`: the time its reader received the
sample, the system clock the player stamps frames with — not when its callback ran, which
waits while the monitor decodes a map; the monitor listens beside the device, so "heard" is
when the device could have it too):

* **summaries** — the slot's last frame captured → the device's frame summaries of the slot
  (the slot's end is seen at the next slot's first frame; then the summary goes out);
* **decision** — summaries → the edge's upload request (the policy, Theorem 1's sizes);
* **uploads** — request → the device's throughput report (the asked keyframes sent through
  the uplink's shaper, paced at the slot's rate);
* **integration** — throughput report → the slot's map update (the keyframes integrated,
  bundle adjustment, evictions, the map serialised and sent);
* **to the device** — map update → the capture of the first frame the device tracked with it
  (a frame's stamp, so up to one frame period late; below zero where the device runs behind
  its camera and tracks a frame captured before the map came).

A stage whose end was not heard (no request, a lost throughput report, no later frame on the
new map) is NaN, and so is the total.

The monitor hears each topic on a reader of its own, and on a loaded host a message can reach
it after the message it caused: the edge's request heard 0.15 ms before the summaries that
caused it (a clean clone's suite). The summaries cause the request, and the request the
device's uploads and their throughput report (CAUSED): where the monitor heard one of these
after the next, the earlier counts as heard when the next was — its effect bounds when it was
out — and the stage between them reads zero. The map update comes of the keyframes, not of the
report, and may be heard before it: the integration stage is not ordered so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msg_schemas.headers import time_seconds
from twinslam.live.run_log import RunLog

#: the stages in loop order, as :class:`SlotLatency` names them
STAGES = ("summaries_s", "decision_s", "uploads_s", "integration_s", "to_device_s")
#: the protocol topics whose receipt ends a stage, in loop order (RunLog.heard's keys)
HEARD = ("summaries", "request", "throughput", "map")
#: how many of HEARD, from the first, each cause the next
CAUSED = 3


@dataclass(frozen=True)
class SlotLatency:
    """The update loop of one slot, stage by stage (seconds)."""

    slot: int
    summaries_s: float
    decision_s: float
    uploads_s: float
    integration_s: float
    to_device_s: float

    @property
    def total_s(self) -> float:
        """The slot's last frame → the first frame tracked on its map."""
        return float(sum(getattr(self, s) for s in STAGES))


def _first_frame_on(record: RunLog, after_slot: int, version: int) -> float:
    """Capture time of the first frame after ``after_slot`` tracked with map ``version`` or a
    newer one; NaN if none came."""
    for slot in sorted(s for s in record.summaries if s > after_slot):
        for f in record.summaries[slot].frames:
            if int(f.map_version) >= version:
                return time_seconds(f.stamp)
    return math.nan


def _in_causal_order(heard: list[float]) -> list[float]:
    """The times HEARD's messages of one slot were heard (NaN: not heard), each of the first
    CAUSED no later than the next one of them: a message that caused another was out by
    then."""
    times = list(heard)
    for i in range(CAUSED - 2, -1, -1):
        if math.isfinite(times[i]) and math.isfinite(times[i + 1]):
            times[i] = min(times[i], times[i + 1])
    return times


def update_loop_latencies(record: RunLog) -> list[SlotLatency]:
    """One :class:`SlotLatency` per slot whose frame summaries were heard."""
    heard = {topic: record.heard.get(topic, {}) for topic in HEARD}
    out = []
    for slot in sorted(heard["summaries"]):
        summary = record.summaries.get(slot)
        if summary is None or not summary.frames:
            continue
        times = [time_seconds(summary.frames[-1].stamp)]
        times += _in_causal_order([heard[t].get(slot, math.nan) for t in HEARD])
        version = record.first_map_versions.get(slot)
        times.append(math.nan if version is None else _first_frame_on(record, slot, version))
        out.append(SlotLatency(slot, *np.diff(times).tolist()))
    return out


def stage_table(latencies: list[SlotLatency]) -> list[tuple[str, float, float, int]]:
    """Per stage and the total: (name, median s, p95 s, slots measured), NaN-free slots
    only."""
    rows = []
    for name in [*STAGES, "total_s"]:
        values = np.array([getattr(x, name) for x in latencies], dtype=np.float64)
        values = values[np.isfinite(values)]
        rows.append((name.removesuffix("_s"),
                     float(np.median(values)) if values.size else math.nan,
                     float(np.percentile(values, 95)) if values.size else math.nan,
                     int(values.size)))
    return rows

