"""Uploads that never starve: where Theorem 1's ⌊d_k·D_req/α⌋ is 0 but the uplink carries a frame
within the slot, the edge and the simulator both ask for one frame a slot; the paper's preset
keeps Theorem 1 exactly; an uplink that cannot carry a frame in the slot uploads none — unless
the device needs a map (new ground, lost), which is served first: its frame goes once the slots
it waited carried one."""

from __future__ import annotations

import numpy as np
import pytest

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.slot_planner import FrameObservations, SlotConfig
from tests.test_edge_core import Device, F, K
from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.slam.keyframe import TRACK_ID_BIT
from twinslam.uncertainty.map_uncertainty import (
    needs_map,
    theorem1_cardinalities,
    theorem1_uploads,
    waited_after,
)
from twinslam.uplink.channels import TraceChannel


def test_the_progress_rule_stretches_the_deadline_only_where_theorem_1_gives_none() -> None:
    # α 5 Mbit, D_req 0.5 s: Theorem 1 uploads nothing under 10 Mbit/s
    assert theorem1_uploads(8.0, 5.0, 0.5, 60) == 0                    # the paper's rule
    assert theorem1_uploads(8.0, 5.0, 0.5, 60, slot_s=2.0) == 1        # 16 Mbit in the slot
    assert theorem1_uploads(2.5, 5.0, 0.5, 60, slot_s=2.0) == 1        # exactly α in the slot
    assert theorem1_uploads(2.0, 5.0, 0.5, 60, slot_s=2.0) == 0        # 4 Mbit: not a frame
    assert theorem1_uploads(0.0, 5.0, 0.5, 60, slot_s=2.0) == 0        # an outage
    assert theorem1_uploads(8.0, 5.0, 0.5, 0, slot_s=2.0) == 0         # no frame to upload
    # where Theorem 1 gives frames the rule changes nothing (Table I's 40-80 Mbit/s)
    assert [theorem1_uploads(r, 5.0, 0.5, 60, 2.0) for r in (10.0, 40.0, 80.0)] == [1, 4, 8]
    # the map makes room for the stretched upload as for any other
    assert theorem1_cardinalities(8.0, 5.0, 0.5, 10, 10, 60, 2.0) == (1, 1)


@pytest.mark.parametrize(("progress", "uploads"), [(True, 1), (False, 0)])
def test_an_edge_under_alpha_over_d_req_still_asks_for_a_frame_a_slot(progress: bool,
                                                                       uploads: int) -> None:
    """At 8 Mbit/s (under α/D_req = 10) the default edge asks for one keyframe a slot and
    integrates it; the paper's preset (``progress_uploads`` false) asks for none."""
    device = Device(np.random.default_rng(1))
    core = EdgeMapperCore(make_policy("lff"), K,
                          EdgeConfig(slot=SlotConfig(vmax=10, progress=progress)))
    # the deadline stretches over the slot of the frames the plan is for: 60 (2 s), where 8
    # Mbit/s carries 16 Mbit; a slot of F = 8 frames (0.27 s) carries 2.1, less than α
    for slot in range(3):
        frames = [device.summary(f, core) for f in range(60 * slot, 60 * (slot + 1))]
        plan = core.plan(slot, frames, 8.0, 0)
        assert len(plan.action.upload) == uploads
        for f in plan.action.upload:
            assert not core.add_keyframe(device.keyframe(f, slot, core)).refused
        out = core.finish_slot(slot)
        assert len(out.integrated) == uploads
    assert len(core.map.keyframes) == 3 * uploads
    short = [device.summary(f, core) for f in range(180, 180 + F)]
    assert not core.plan(3, short, 8.0, 0).action.upload


@pytest.mark.parametrize(("config", "uploads"),
                         [(SimConfig(vmax=5, slot_frames=60, slots=6), 1),
                          (SimConfig.paper_rule(vmax=5, slot_frames=60, slots=6), 0)])
def test_the_simulator_models_the_same_rule(config: SimConfig, uploads: int) -> None:
    """The simulator's |U_k| at 8 Mbit/s is the edge's: one with the progress rule, none with
    the paper's rule."""
    # a camera that hardly moves: every frame stays tracked, so every slot has candidates
    data = CovisibilityDataset.from_sets([np.arange(i // 30, i // 30 + 100) for i in range(600)])
    channel = TraceChannel.from_samples(np.arange(40.0), np.full(40, 8.0), 1)   # 8 Mbit/s
    env = MapManagementEnv(data, channel, config)
    obs, _ = env.reset(seed=0)
    sizes = []
    for _ in range(4):
        sizes.append(obs.n_upload)
        obs, *_ = env.step(make_policy("lff").decide(obs))
    assert sizes == [uploads] * 4


def test_a_device_that_needs_a_map_waits_for_what_the_uplink_carried_over_the_slots() -> None:
    # α 5 Mbit, D_req 0.5 s, 2 s slots at 2 Mbit/s: 4 Mbit a slot, never a frame on its own
    assert theorem1_uploads(2.0, 5.0, 0.5, 60, 2.0) == 0
    waited = waited_after(0, 2.0, 2.0, 0.0, needs_map([False, True]))     # new ground: 4 Mbit
    assert waited == pytest.approx(4.0)
    assert theorem1_uploads(2.0, 5.0, 0.5, 60, 2.0, waited) == 1          # 8 Mbit: the frame goes
    assert waited_after(1, 2.0, 2.0, waited, True) == 0.0                 # served: wait anew
    # a device its map still tracks (its newest frame tracked) waits for nothing
    assert waited_after(0, 2.0, 2.0, 4.0, needs_map([True, False])) == 0.0
    assert not needs_map([])
    # the paper's preset (no progress rule) carries nothing, and an outage adds nothing
    assert waited_after(0, 2.0, 0.0, 4.0, True) == 0.0
    assert waited_after(0, 0.0, 2.0, 4.0, True) == pytest.approx(4.0)
    assert theorem1_uploads(2.0, 5.0, 0.5, 60, 0.0, 100.0) == 0


#: one walk, slot by slot, for the edge and the simulator alike: (the slot's rate in Mbit/s,
#: whether its last ten frames look away from everything mapped). Slot 0 carries a frame by
#: the progress rule; slot 2 ends in new ground at 2 Mbit/s (4 Mbit a slot, under α); slot 3
#: looks back at the map and gets the frame the two slots carried; nothing else needs one.
WALK = [(8.0, False), (2.0, False), (2.0, True), (2.0, False), (2.0, False)]
SERVED = [1, 0, 0, 1, 0]


def test_the_edge_serves_a_device_in_new_ground_first() -> None:
    device = Device(np.random.default_rng(2))
    core = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(slot=SlotConfig(vmax=10)))
    uploads = []
    for slot, (rate, away) in enumerate(WALK):
        ids = range(60 * slot, 60 * (slot + 1))
        if slot == 0:       # the device's start-up frames, integrated into an empty map
            frames = [device.summary(f, core) for f in ids]
        else:
            seen = frozenset(core.map.points)
            frames = [FrameObservations(f, frozenset() if away and f >= ids[-10] else seen,
                                        frozenset({int(TRACK_ID_BIT) | f})) for f in ids]
        plan = core.plan(slot, frames, rate, 0)
        uploads.append(len(plan.action.upload))
        if slot == 0:
            for f in plan.action.upload:
                assert not core.add_keyframe(device.keyframe(f, slot, core)).refused
            core.finish_slot(slot)
    assert uploads == SERVED


def test_the_simulator_serves_a_device_in_new_ground_first() -> None:
    sets = [np.arange(1000, 1100) if 170 <= i < 180 else np.arange(100) for i in range(300)]
    data = CovisibilityDataset.from_sets(sets)
    channel = TraceChannel.from_samples(np.arange(40.0), np.full(40, 8.0), 1)
    env = MapManagementEnv(data, channel, SimConfig(vmax=5, slot_frames=60, slots=5, start=0))
    obs, _ = env.reset(seed=0)
    uploads, served = [], None
    for slot, (rate, _away) in enumerate(WALK):
        env.set_rate(rate)
        obs = env.observation()
        uploads.append(obs.n_upload)
        if slot == 3:
            served = env.snapshot()
        if slot < len(WALK) - 1:
            obs, *_ = env.step(make_policy("lff").decide(obs))
    assert uploads == SERVED
    # a snapshot keeps what was waited for: a search that restores one sees the same sizes
    assert served is not None
    env.restore(served)
    assert env.observation().n_upload == 1
