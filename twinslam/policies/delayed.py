"""``delay:SECONDS:POLICY`` — a policy's own decisions, each handed back SECONDS late.

A control for live runs: a planner that thinks longer at the edge delays the slot's upload
request, the keyframes and so the device's next map. Running a rule policy with the planner's
decision time added tells that cost apart from the planner's choices (docs/results/planning.md: the
causal planner live). Only wall time changes; the decisions are the wrapped policy's.
"""

from __future__ import annotations

import math
import time

from twinslam.policies.actions import MapAction, SlotObservation
from twinslam.policies.protocol import MapPolicy, SlotViewer

DELAY_PREFIX = "delay"


def parse_delay(name: str) -> tuple[float, str]:
    """(seconds, the wrapped policy's name) of ``delay:SECONDS:POLICY``; ValueError naming
    what is wrong."""
    _, _, rest = name.partition(":")
    seconds, sep, inner = rest.partition(":")
    try:
        delay = float(seconds)
    except ValueError:
        delay = math.nan
    if not sep or not inner or not math.isfinite(delay) or not 0 <= delay <= 60:
        raise ValueError(f"policy {name!r}: use delay:SECONDS:POLICY with 0 <= SECONDS <= 60, "
                         "e.g. delay:0.3:lff")
    return delay, inner


class DelayedPolicy:
    """``policy``'s decisions, ``seconds`` after they were asked for."""

    def __init__(self, policy: MapPolicy, seconds: float) -> None:
        self.policy, self.seconds = policy, float(seconds)
        self.name = f"{DELAY_PREFIX}:{seconds:g}:{policy.name}"

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed)

    def see_slot(self, view: object) -> None:
        """What the slot planner shows a policy that predicts the camera's view (``mpc`` at
        the edge), passed on to the wrapped one."""
        if isinstance(self.policy, SlotViewer):
            self.policy.see_slot(view)

    def decide(self, obs: SlotObservation) -> MapAction:
        started = time.perf_counter()
        action = self.policy.decide(obs)
        time.sleep(max(0.0, self.seconds - (time.perf_counter() - started)))
        return action
