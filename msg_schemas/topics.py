"""Topic names of the per-slot protocol and the camera, written once (docs/architecture.md §1).

All are relative, so a node's namespace moves them: ``-r __ns:=/ar1`` on a device and its edge
puts the pair on ``/ar1/device/...`` and ``/ar1/edge/...``, and a second pair under ``/ar2``
shares the domain without cross-talk.
"""

CAMERA_IMAGE = "camera/image_raw"
CAMERA_DEPTH = "camera/depth/image_raw"
CAMERA_INFO = "camera/camera_info"
GROUND_TRUTH_POSE = "camera/ground_truth_pose"
GROUND_TRUTH_PATH = "camera/ground_truth_path"

DEVICE_POSE = "device/pose"
DEVICE_PATH = "device/path"
#: the camera in REP 105's continuous odom frame (nav_msgs/Odometry, pose only)
DEVICE_ODOM = "device/odom"
FRAME_SUMMARIES = "device/frame_summaries"
KEYFRAMES = "device/keyframes"
UPLINK_THROUGHPUT = "device/uplink_throughput"
#: a lost device's frame for relocalisation at the edge, and the edge's answer
RELOCALISATION_REQUEST = "device/relocalisation_request"
RELOCALISATION = "edge/relocalisation"

UPLOAD_REQUEST = "edge/upload_request"
MAP_UPDATE = "edge/map_update"
MAP_STATS = "edge/map_stats"
#: what a viewer shows (standard messages, edge_mapper.visual_messages)
MAP_POINTS = "edge/map_points"
KEYFRAME_POSES = "edge/keyframes"
DECISIONS = "edge/decisions"
#: every keyframe the edge keeps, the map's and the archive's, as nav_msgs/Path
KEYFRAME_TRAJECTORY = "edge/keyframe_trajectory"
#: an edge serving several devices: how it splits its keyframe budget
KEYFRAME_BUDGET = "edge/keyframe_budget"

RATE_LATENT = "udt/rate_latent"

#: the TF tree (msg_schemas.transforms): absolute, as tf2 and every viewer expect, so a
#: namespace does not move them; devices sharing a domain keep apart by their frame ids
TF = "/tf"
TF_STATIC = "/tf_static"
#: node health (diagnostic_msgs/DiagnosticArray): absolute, where ROS 2's diagnostic
#: aggregator, rqt_runtime_monitor and Foxglove look; the player says there what it played
#: and what it skipped
DIAGNOSTICS = "/diagnostics"
#: paced cameras that keep one recording clock (the player's ``pace_group``): each says on
#: ``/playback_pace/GROUP`` how long it held (twinslam_msgs/PlaybackPace); absolute, so that
#: the cameras of a fleet's namespaces (``/ar1``, ``/ar2``) meet on it
PLAYBACK_PACE = "/playback_pace"
