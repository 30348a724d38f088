"""The twin node's message: a latent as ``RateLatent`` (pure conversion, no DDS)."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from twinslam_msgs.msg import RateLatent

from msg_schemas import new
from twinslam.twin.rate_model import Latent


def rate_latent_message(slot: int, latent: Latent, state_rates_mbps: np.ndarray, stamp: Time,
                        frame_id: str) -> RateLatent:
    """Slot ``slot``'s latent, stamped like the throughput report it answers."""
    out: RateLatent = new(RateLatent, slot=int(slot), model_version=latent.model_version,
                          mu=latent.mu.astype(np.float32),
                          sigma=latent.sigma.astype(np.float32),
                          next_state_probs=latent.next_state_probs.astype(np.float32),
                          state_rates_mbps=state_rates_mbps.astype(np.float64))
    out.header.stamp = stamp
    out.header.frame_id = frame_id
    return out
