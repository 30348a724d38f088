"""The twin's latent [μ, Σ] as the policy's features, in numpy only.

The edge receives the twin node's latent as a message and hands it to the learned policy; it
must do so without importing torch (an edge on ``policy:=lff`` never loads it), so the one
conversion both sides use lives here rather than beside the torch rate models.
"""

from __future__ import annotations

import numpy as np

LOG_SIGMA_FLOOR = 1e-12        #: Σ below this enters the state as log(1e-12) ≈ -27.6


def latent_features(mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """The twin's latent as the policy's state sees it: [μ, log Σ]. A confident twin's Σ
    underflows float32 (exp of log Σ < -87 is 0): clipped before the log, or the state holds
    -inf and the networks NaN."""
    log_sigma = np.log(np.clip(np.asarray(sigma, dtype=np.float64), LOG_SIGMA_FLOOR, None))
    return np.concatenate([np.asarray(mu, dtype=np.float64), log_sigma]).astype(np.float32)
