"""The slot protocol's settings are written once: the edge's planner and the simulator hold
the same V_max, α, D_req and progress rule, refuse the same impossible values, and stretch the
same deadline."""

from __future__ import annotations

import math

import pytest

from edge_mapper.slot_planner import SlotConfig
from twinslam.policies.world_model import SimConfig
from twinslam.slot_protocol import table1
from twinslam.slot_protocol.slot_settings import SlotSettings


@pytest.mark.parametrize("config", [SlotConfig, SimConfig])
@pytest.mark.parametrize(("field", "value"), [("vmax", -1), ("alpha_mbit", 0.0),
                                              ("alpha_mbit", math.inf), ("d_req_s", 0.0),
                                              ("d_req_s", math.nan)])
def test_a_setting_no_slot_could_run_with_is_refused_by_the_edge_and_the_simulator(
        config: type[SlotSettings], field: str, value: float) -> None:
    with pytest.raises(ValueError, match=r"V_max|alpha|D_req"):
        config(**{field: value})


def test_the_edge_and_the_simulator_stretch_the_same_deadline() -> None:
    edge, sim = SlotConfig(), SimConfig(slot_frames=30)
    assert (edge.vmax, edge.alpha_mbit, edge.d_req_s) == (sim.vmax, sim.alpha_mbit, sim.d_req_s)
    assert (edge.vmax, edge.alpha_mbit, edge.d_req_s) == (
        table1.VMAX, table1.ALPHA_MBIT, table1.D_REQ_S)
    assert edge.deadline_s(30) == sim.slot_seconds == pytest.approx(1.0)       # 30 Hz
    # the paper's preset: Theorem 1 exactly, no deadline to stretch
    assert SlotConfig(progress=False).deadline_s(30) == 0.0
    assert SimConfig.paper_rule(slot_frames=30).slot_seconds == 0.0
    with pytest.raises(ValueError, match="at least one frame"):
        SimConfig(slot_frames=0)
