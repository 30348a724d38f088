"""The paper's Table I: the defaults every layer starts from, written once here.

Zhou et al. simulate slots of F = 60 frames, an edge map of at most V_max = 45 keyframes, a
compressed frame of α = 5 Mbit that must reach the edge within D_req = 0.5 s, and an uplink
between 40 and 80 Mbit/s. The simulator, the nodes' parameters, the trainer and the command
line all default to these names, so changing a default is one edit.
"""

from __future__ import annotations

VMAX = 45                        #: V_max, keyframes the edge map holds at most
SLOT_FRAMES = 60                 #: F, frames per slot
FRAME_RATE_HZ = 30.0             #: the camera's nominal rate (a slot lasts F / this seconds)
ALPHA_MBIT = 5.0                 #: α, Mbit one uploaded frame occupies on the uplink
D_REQ_S = 0.5                    #: D_req, seconds a slot's uploads may take
RATE_MIN_MBPS = 40.0             #: the uplink's lowest rate state
RATE_MAX_MBPS = 80.0             #: the uplink's highest rate state
RATE_RANGE_MBPS = (RATE_MIN_MBPS, RATE_MAX_MBPS)
