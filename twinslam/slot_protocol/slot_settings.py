"""The settings of the slot protocol, written once: what the edge's planner and the simulator
both plan a slot with.

A slot uploads |U_k| = ⌊d_k · D_req / α⌋ frames into a map of at most V_max keyframes (paper
Theorem 1); where that floor is 0 but the uplink carries α within the slot, the **progress
rule** asks for one frame, its deadline stretched to the slot's end (DESIGN.md §7b). The edge's
:class:`~edge_mapper.slot_planner.SlotConfig` and the simulator's
:class:`~twinslam.policies.world_model.SimConfig` are these settings and what each adds (the
simulator its slot length F and its episode; the edge reads F off each slot's summaries), so
a default or a check changed here changes for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from twinslam.slot_protocol import table1


@dataclass(frozen=True)
class SlotSettings:
    """V_max, α and D_req of Table I by default, and the progress rule on."""

    vmax: int = table1.VMAX
    alpha_mbit: float = table1.ALPHA_MBIT
    d_req_s: float = table1.D_REQ_S
    #: the progress rule (the edge's ``progress_uploads``): where D_req carries no frame but
    #: the slot does, one goes; False: Theorem 1 exactly, the paper's
    progress: bool = True

    def __post_init__(self) -> None:
        if self.vmax < 0:
            raise ValueError(f"V_max must be >= 0 keyframes, got {self.vmax}")
        if not 0 < self.alpha_mbit < math.inf:
            raise ValueError(f"alpha must be a positive number of Mbit, got {self.alpha_mbit}")
        if not 0 < self.d_req_s < math.inf:
            raise ValueError(f"D_req must be a positive number of seconds, got {self.d_req_s}")

    def deadline_s(self, slot_frames: int) -> float:
        """The deadline the progress rule stretches to for a slot of ``slot_frames`` camera
        frames: the slot's length at the camera's rate (0 with the rule off, where Theorem 1
        alone decides)."""
        return slot_frames / table1.FRAME_RATE_HZ if self.progress else 0.0
