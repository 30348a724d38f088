"""One slot of the live protocol with the device and edge cores in one process: the frames'
summaries to the edge, its plan, the uploads it asked for, the slot's end and the map update
back to the device — the nodes' work without DDS and without the uplink's delay, for the
benchmarks that drive whole walks through the cores.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from device_tracker.device_core import DeviceTrackerCore
from device_tracker.messages import read_map_update
from edge_mapper.edge_core import EdgeMapperCore, SlotOutcome
from edge_mapper.messages import map_update_message
from edge_mapper.slot_planner import FrameObservations
from twinslam.slam.map_update import MapSnapshot


@dataclass(frozen=True)
class ServedSlot:
    """What the edge made of a slot, and how long each of its steps took."""

    outcome: SlotOutcome
    plan_ms: float          #: the policy's decision with its observation
    integrate_ms: float     #: the requested keyframes added to the map
    finish_ms: float        #: eviction, bundle adjustment, checkpoint, uncertainty
    #: the map update, when the caller applies it itself (``hold``); None: applied already
    update: MapSnapshot | None = None


def serve_slot(device: DeviceTrackerCore, edge: EdgeMapperCore, rate_mbps: float,
               rate_state: int, hold: bool = False) -> ServedSlot:
    """The device's finished slot through the edge, and the new map applied at the device
    at once. The summaries carry what the edge node reads from the wire: the observed points
    and tracks, the tracked flag and the pose (``mpc`` predicts from the poses; an untracked
    frame is never uploaded). ``hold``: the update is returned for the caller to apply later
    (as a live device gets it some frames into the next slot)."""
    frames = device.take_slot()
    slot = frames[-1].slot
    summaries = [FrameObservations(f.frame_id, frozenset(f.map_point_ids.tolist()),
                                   frozenset(f.track_ids.tolist()), bool(f.tracked), f.pose,
                                   f.map_version)
                 for f in frames]
    t0 = time.perf_counter()
    plan = edge.plan(slot, summaries, rate_mbps, rate_state)
    t1 = time.perf_counter()
    for frame_id in plan.action.upload:
        payload = device.upload(frame_id)
        if payload is None:
            raise RuntimeError(f"slot {slot}: the device no longer holds frame {frame_id}, "
                               "which the edge asked for in the same slot")
        edge.add_keyframe(payload)
    t2 = time.perf_counter()
    outcome = edge.finish_slot(slot)
    t3 = time.perf_counter()
    update = map_update_message(edge.map, slot, outcome.version, time.time(),
                                tracks=outcome.tracks, frame_correction=edge.frame_correction)
    snapshot = read_map_update(update)
    if hold:
        return ServedSlot(outcome, (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3, snapshot)
    device.apply_map_update(snapshot, slot)
    return ServedSlot(outcome, (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3)
