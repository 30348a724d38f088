"""The device node's ROS parameters: name, default, description and range.

Defaults are the default device's (:mod:`twinslam.slot_protocol.default_device`: 30-frame
slots, the edge's map and the device's own points) and the paper's Table I elsewhere (α 5 Mbit,
40–80 Mbit/s); ``config/paper-table1.yaml`` is the paper's device. ``ros2 param describe
/device_tracker channel`` shows the description.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from twinslam.node_runtime.parameters import ParamSpec
from twinslam.slam.front_end.map_source import DEFAULT_MAP_SOURCE, check_map_source
from twinslam.slam.front_end.tracking import TrackingConfig
from twinslam.slam.pose_plausibility import MotionBounds
from twinslam.slot_protocol import default_device, table1
from twinslam.uplink.tc_shaper import SHAPERS

PARAMETERS = (
    ParamSpec("slot_frames", default_device.SLOT_FRAMES, "F, frames per slot (Table I: 60)",
              low=1, high=100_000),
    ParamSpec("frame_rate_hz", table1.FRAME_RATE_HZ, "nominal camera rate (Hz, x the player's "
              "rate when replaying faster); a slot is slot_frames / frame_rate_hz seconds of "
              "frame stamps, so a lost frame does not shift later slots", low=1e-3, high=1e5),
    ParamSpec("alpha_mbit", table1.ALPHA_MBIT, "alpha, uplink Mbit one uploaded frame occupies "
              "(at least)", low=1e-6, high=1e6),
    ParamSpec("channel", "markov:N=2", "uplink rate model: markov:N=2[,K=...], "
              "trace:FILE[,N=4] (CSV time_s,throughput_mbps) or generated:regime=S,"
              "outage_every=S,outage=S,range=MIN-MAX (a trace drawn from seed)"),
    ParamSpec("rate_min", table1.RATE_MIN_MBPS, "Mbit/s the channel's lowest state", low=0.0,
              high=1e6),
    ParamSpec("rate_max", table1.RATE_MAX_MBPS, "Mbit/s the channel's highest state", low=0.0,
              high=1e6),
    ParamSpec("seed", 0, "seed of the channel model", low=0),
    ParamSpec("n_features", 1000, "ORB features per frame", low=10, high=100_000),
    ParamSpec("reloc_min_inliers", TrackingConfig.reloc_min_inliers, "the pose gate: RANSAC "
              "inliers a relocalised pose needs after refinement (bench.relocalisation_gate)",
              low=4, high=100_000),
    ParamSpec("reloc_probation_frames", TrackingConfig.reloc_probation_frames, "frames a "
              "relocalised device must track by its motion model before it counts itself "
              "tracked and uploads again (0: none)", low=0, high=100_000),
    ParamSpec("depth_baseline_m", TrackingConfig.depth_baseline_m, "the virtual stereo "
              "baseline (metres) each tracked feature's depth reading is weighed by when the "
              "motion model's pose is refined (ORB-SLAM2's RGB-D bf over fx: the depth as a "
              "right-image coordinate); readings beyond 40 baselines count as none; 0: the "
              "refinement uses the pixels alone", low=0.0, high=10.0),
    ParamSpec("max_view_angle_deg", TrackingConfig.max_view_angle_deg, "a map point is "
              "searched for only where the camera sees it within this many degrees of the "
              "direction the map's keyframes saw it from (ORB-SLAM's local map search: 60); "
              "180: every point in the image is", low=1.0, high=180.0),
    ParamSpec("max_step_m", MotionBounds.max_step_m, "the motion gate: metres the camera may "
              "move between two frames; a tracked pose farther from the last posed frame is "
              "refused and the frame lost, for relocalisation to bring back "
              "(twinslam/slam/pose_plausibility.py; bench.motion_bounds measures a sequence)",
              low=1e-3, high=1e3),
    ParamSpec("max_turn_deg", MotionBounds.max_turn_deg, "the motion gate: degrees the camera "
              "may turn between two frames", low=1e-3, high=180.0),
    ParamSpec("max_speed_m_s", MotionBounds.max_speed_m_s, "the motion gate: metres a second "
              "the camera may move, sustained over half a second", low=1e-3, high=1e4),
    ParamSpec("reloc_period_s", 0.0, "while lost, the newest lost frame's features (~40 kB, "
              "no image) go to the edge for relocalisation against its archive this often "
              "(seconds of frame stamps; the first at once; 0.5 as Edge-SLAM; the edge's "
              "reloc_restore_keyframes must be on); 0: never", low=0.0, high=3600.0),
    ParamSpec("own_map_after_s", default_device.OWN_MAP_AFTER_S, "the paper's device "
              "(map_source edge) lost this long "
              "(seconds of frame stamps) tracks on with points of its own — the features it "
              "follows for the edge, from depth — and the edge's map, as edge+local, until "
              "the edge's map explains its view again, so its frames can be uploaded; 0: "
              "never, it waits for the edge's map", low=0.0, high=3600.0),
    ParamSpec("map_frame", "map", "frame id of the device's poses and path (its first "
              "frame's camera frame) and parent of the camera on /tf"),
    ParamSpec("camera_frame", "", "child frame of the device's pose on /tf; empty: the camera "
              "images' own frame id (the player's frame_id), so a viewer places the images"),
    ParamSpec("publish_tf", True, "broadcast the camera's pose on /tf for every tracked frame "
              "(off where another node owns those transforms)"),
    ParamSpec("odom_frame", "odom", "REP 105's continuous frame: /tf carries map_frame -> "
              "odom_frame (every correction of the map pose: map updates, relocalisations) "
              "and odom_frame -> camera (the device's own motion, never leaping), and "
              "device/odom the camera in it; empty: map_frame -> camera directly, no "
              "device/odom"),
    ParamSpec("path_window", 900, "poses device/path holds: the newest ones (900: 30 s at "
              "30 Hz); the whole run is on device/pose", low=1, high=10_000_000),
    ParamSpec("shaper", "token_bucket", "uplink shaper: token_bucket (in process) or tc (a "
              "tbf of rate d_k on uplink_interface; CAP_NET_ADMIN)",
              check=lambda v: None if v in SHAPERS else f"must be one of {', '.join(SHAPERS)}"),
    ParamSpec("uplink_interface", "eth0", "interface tc shapes (shaper:=tc)"),
    ParamSpec("netem_delay_ms", 0.0, "tc netem delay on the uplink (kernels with sch_netem)",
              low=0.0, high=60_000.0),
    ParamSpec("netem_loss_percent", 0.0, "tc netem random loss on the uplink", low=0.0,
              high=100.0),
    ParamSpec("upload_image", False, "keyframes carry their colour image too (real frame "
              "bytes on the link)"),
    ParamSpec("edge_timeout_s", 3.0, "no upload request for this long: say the edge is silent",
              low=0.01, high=3600.0),
    ParamSpec("map_source", DEFAULT_MAP_SOURCE, "where poses come from: edge (only the points "
              "of the edge's last map update, the paper's device: what the edge keeps decides "
              "tracking) or edge+local (plus the device's own points of its last "
              "keep_slots slots, an Edge-SLAM style device; the default, measured best on "
              "every uplink family); changes live, from the next frame",
              live=True, check=check_map_source),
    ParamSpec("keep_slots", 4, "slots whose frames stay uploadable (rides out ~5 s outages)",
              low=1, high=1000),
)


@dataclass(frozen=True)
class DeviceSettings:
    """The parameters the node reads once at start, typed (the live ``map_source`` is read
    again at every frame; the uplink's are :mod:`device_tracker.uplink_setup`'s)."""

    slot_frames: int
    frame_rate_hz: float
    alpha_bytes: int               #: α in bytes: the least a keyframe occupies on the link
    channel: str
    map_frame: str
    camera_frame: str              #: "" takes the images' frame id
    publish_tf: bool
    map_source: str
    tracking: TrackingConfig
    upload_image: bool
    keep_slots: int                #: 4 ride out a link down for ~5 s
    path_window: int
    reloc_period_s: float = 0.0    #: while lost, a frame to the edge's archive this often
    own_map_after: int = 0         #: frames lost in a row before the paper's device maps itself
    odom_frame: str = "odom"       #: REP 105's continuous frame ("": none, map -> camera)

    @classmethod
    def from_parameters(cls, p: Mapping[str, Any]) -> DeviceSettings:
        """ValueError where two parameters contradict each other."""
        if p["camera_frame"] and p["camera_frame"] == p["map_frame"]:
            raise ValueError(f"camera_frame and map_frame are both {p['map_frame']!r}: the "
                             "camera's pose on /tf needs two frames")
        if p["odom_frame"] and p["odom_frame"] in (p["map_frame"], p["camera_frame"]):
            raise ValueError(f"odom_frame {p['odom_frame']!r} is also the map or camera "
                             "frame: map -> odom -> camera needs three frames")
        rate = float(p["frame_rate_hz"])
        motion = MotionBounds(max_step_m=float(p["max_step_m"]),
                              max_turn_deg=float(p["max_turn_deg"]),
                              max_speed_m_s=float(p["max_speed_m_s"]),
                              speed_window=max(2, round(rate / 2)))
        tracking = TrackingConfig(n_features=int(p["n_features"]), relocalise=True,
                                  reloc_min_inliers=int(p["reloc_min_inliers"]),
                                  reloc_probation_frames=int(p["reloc_probation_frames"]),
                                  depth_baseline_m=float(p["depth_baseline_m"]),
                                  max_view_angle_deg=float(p["max_view_angle_deg"]),
                                  motion=motion, frame_rate_hz=rate)
        return cls(slot_frames=int(p["slot_frames"]), frame_rate_hz=rate,
                   alpha_bytes=int(float(p["alpha_mbit"]) * 1e6 / 8), channel=str(p["channel"]),
                   map_frame=str(p["map_frame"]), camera_frame=str(p["camera_frame"]),
                   publish_tf=bool(p["publish_tf"]), map_source=str(p["map_source"]),
                   tracking=tracking, upload_image=bool(p["upload_image"]),
                   keep_slots=int(p["keep_slots"]), path_window=int(p["path_window"]),
                   reloc_period_s=float(p["reloc_period_s"]),
                   own_map_after=round(float(p["own_map_after_s"]) * rate),
                   odom_frame=str(p["odom_frame"]))

    def describe(self, shaper: str) -> str:
        """The start-up line."""
        return (f"slots of {self.slot_frames} frames ({self.slot_frames / self.frame_rate_hz:g}"
                f" s of stamps), map source {self.map_source}, channel {self.channel}, uplink "
                f"shaper {shaper}")
