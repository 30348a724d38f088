"""What a monitor hears of a live run, kept by slot: the raw material of every report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from twinslam_msgs.msg import FrameSummaries, MapStats, RateLatent, UplinkThroughput, UploadRequest

from twinslam.slam.map_update import MapSnapshot


@dataclass
class RunRecord:
    """Everything the monitor heard, by slot (messages as received)."""

    summaries: dict[int, FrameSummaries] = field(default_factory=dict)
    requests: dict[int, UploadRequest] = field(default_factory=dict)
    stats: dict[int, MapStats] = field(default_factory=dict)
    throughput: dict[int, UplinkThroughput] = field(default_factory=dict)
    maps: dict[int, MapSnapshot] = field(default_factory=dict)   #: last map update per slot
    poses: dict[int, np.ndarray] = field(default_factory=dict)        #: stamp ns → pose
    ground_truth: dict[int, np.ndarray] = field(default_factory=dict)
    latents: dict[int, RateLatent] = field(default_factory=dict)    #: the twin's, by slot
    images_received: int = 0        #: /camera/image_raw samples, when the monitor watches them
    #: bytes the edge sent the device: map updates and relocalisation answers, as serialised
    downlink_bytes: int = 0
