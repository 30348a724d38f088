"""What a monitor hears of a live run, kept by slot: the raw material of every report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from twinslam_msgs.msg import FrameSummaries, MapStats, RateLatent, UplinkThroughput, UploadRequest

from twinslam.slam.map_update import MapSnapshot


@dataclass
class RunLog:
    """Everything the monitor heard, by slot (messages as received)."""

    summaries: dict[int, FrameSummaries] = field(default_factory=dict)
    requests: dict[int, UploadRequest] = field(default_factory=dict)
    stats: dict[int, MapStats] = field(default_factory=dict)
    throughput: dict[int, UplinkThroughput] = field(default_factory=dict)
    maps: dict[int, MapSnapshot] = field(default_factory=dict)   #: last map update per slot
    #: each of those map updates' header stamp (ns)
    map_stamps: dict[int, int] = field(default_factory=dict)
    #: the newest edge/keyframe_trajectory: every keyframe the edge kept, archived ones
    #: included, by capture stamp (ns) → camera-to-map pose; and that message's stamp (ns)
    keyframe_trajectory: dict[int, np.ndarray] = field(default_factory=dict)
    trajectory_stamp: int = -1
    poses: dict[int, np.ndarray] = field(default_factory=dict)        #: stamp ns → pose
    #: stamp ns → the camera's pose in REP 105's odom frame (device/odom)
    odom_poses: dict[int, np.ndarray] = field(default_factory=dict)
    ground_truth: dict[int, np.ndarray] = field(default_factory=dict)
    latents: dict[int, RateLatent] = field(default_factory=dict)    #: the twin's, by slot
    images_received: int = 0        #: /camera/image_raw samples, when the monitor watches them
    #: frames the player could not read and left out, as its last status on /diagnostics said
    #: (None: it said nothing)
    frames_skipped: int | None = None
    #: bytes the edge sent the device: map updates and relocalisation answers, as serialised
    downlink_bytes: int = 0
    #: when the monitor first heard each slot's message of a protocol topic ("summaries",
    #: "request", "throughput", "map" → slot → seconds on the system clock, the
    #: clock the player stamps frames with): the update loop's stages
    #: (:mod:`twinslam.live.update_loop`)
    heard: dict[str, dict[int, float]] = field(default_factory=dict)
    #: the version of each slot's first map update (``maps`` keeps the last: a relocalisation
    #: answer may send the slot's map again, newer)
    first_map_versions: dict[int, int] = field(default_factory=dict)

    def hear(self, topic: str, slot: int, now: float) -> None:
        """Note ``now`` as when ``topic``'s message of ``slot`` came, unless one came
        before."""
        self.heard.setdefault(topic, {}).setdefault(slot, now)
