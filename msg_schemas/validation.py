"""Semantic checks on decoded messages: the CDR was well formed, but does the content make sense?

The middleware drops payloads that are not valid CDR of the topic type before they reach Python
(Fast DDS's type support refuses them); what reaches us can still be malformed as a message:
an image whose buffer is shorter than ``height * step``, a NaN pose, descriptor arrays that do
not match the keypoint count. A node must refuse those with a logged reason (docs/architecture.md
§8) instead of crashing deep in a callback.
Each validator raises :class:`MessageError` with a reason a user can act on.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

#: bytes per pixel of the image encodings twinslam produces and consumes
ENCODING_BYTES = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 2,
                  "16UC1": 2, "32FC1": 4, "8UC1": 1, "8UC3": 3}
ORB_DESCRIPTOR_BYTES = 32


class MessageError(ValueError):
    """A message whose content is inconsistent; the reason says which field and why."""


def _finite(name: str, *values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise MessageError(f"{name} holds a non-finite value: {values}")


def _pose(name: str, pose: Any) -> None:
    p, q = pose.position, pose.orientation
    _finite(f"{name}.position", p.x, p.y, p.z)
    _finite(f"{name}.orientation", q.x, q.y, q.z, q.w)
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(norm - 1.0) > 1e-3:
        raise MessageError(f"{name}.orientation is not a unit quaternion (norm {norm:.6f})")


def validate_image(msg: Any, name: str = "image", allow_empty: bool = False) -> None:
    if allow_empty and msg.height == 0 and msg.width == 0 and len(msg.data) == 0:
        return
    bpp = ENCODING_BYTES.get(msg.encoding)
    if bpp is None:
        raise MessageError(f"{name}: unsupported encoding {msg.encoding!r}; "
                           f"supported: {sorted(ENCODING_BYTES)}")
    if msg.height == 0 or msg.width == 0:
        raise MessageError(f"{name}: empty image {msg.width}x{msg.height}")
    if msg.step < msg.width * bpp:
        raise MessageError(f"{name}: step {msg.step} < width {msg.width} x {bpp} bytes")
    if len(msg.data) != msg.height * msg.step:
        raise MessageError(f"{name}: data holds {len(msg.data)} bytes, height x step is "
                           f"{msg.height * msg.step} (truncated or padded payload)")


def validate_camera_info(msg: Any) -> None:
    k = np.asarray(msg.k, dtype=float)
    if not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
        raise MessageError(f"camera_info: intrinsics K must be finite with fx, fy > 0, got {k}")


def validate_pose_stamped(msg: Any) -> None:
    _pose("pose", msg.pose)


def validate_frame_summaries(msg: Any) -> None:
    _finite("rate_mbps", msg.rate_mbps)
    if msg.rate_mbps < 0:
        raise MessageError(f"rate_mbps must be >= 0, got {msg.rate_mbps}")
    ids = [f.frame_id for f in msg.frames]
    if len(set(ids)) != len(ids):
        raise MessageError("frames repeat a frame_id")
    for frame in msg.frames:
        if frame.tracked:
            _pose(f"frames[{frame.frame_id}].pose", frame.pose)
        _finite(f"frames[{frame.frame_id}].cpu_ms", frame.cpu_ms)
        if frame.cpu_ms < 0:
            raise MessageError(f"frames[{frame.frame_id}].cpu_ms must be >= 0, got "
                               f"{frame.cpu_ms}")


def validate_upload_request(msg: Any) -> None:
    _finite("rate_mbps", msg.rate_mbps)
    if len(set(msg.upload_frame_ids)) != len(msg.upload_frame_ids):
        raise MessageError("upload_frame_ids repeat an id")


def _features(msg: Any) -> int:
    """The keypoint count of a message carrying ORB features (``keypoints_xy``,
    ``descriptors``) and intrinsics ``k``, checked: pairs of finite pixels, 32 descriptor
    bytes a keypoint, finite intrinsics."""
    n = len(msg.keypoints_xy) // 2
    if len(msg.keypoints_xy) % 2:
        raise MessageError(f"keypoints_xy has odd length {len(msg.keypoints_xy)}")
    if len(msg.descriptors) != n * ORB_DESCRIPTOR_BYTES:
        raise MessageError(f"descriptors hold {len(msg.descriptors)} bytes for {n} keypoints "
                           f"(expected {n * ORB_DESCRIPTOR_BYTES})")
    if n and not np.all(np.isfinite(msg.keypoints_xy)):
        raise MessageError("keypoints_xy holds non-finite values")
    if not np.all(np.isfinite(np.asarray(msg.k))):
        raise MessageError("intrinsics k hold non-finite values")
    return n


def validate_keyframe(msg: Any) -> None:
    n = _features(msg)
    for field, arr in (("keypoint_depths", msg.keypoint_depths),
                       ("map_point_ids", msg.map_point_ids)):
        if len(arr) not in (0, n):
            raise MessageError(f"{field} has {len(arr)} entries for {n} keypoints")
    _pose("pose_estimate", msg.pose_estimate)
    validate_image(msg.image, "image", allow_empty=True)
    validate_image(msg.depth, "depth", allow_empty=True)
    if n == 0 and msg.image.height == 0:
        raise MessageError("keyframe carries neither an image nor features")


def validate_relocalisation_request(msg: Any) -> None:
    if _features(msg) == 0:
        raise MessageError("a relocalisation request carries no features")


def validate_relocalisation(msg: Any) -> None:
    if msg.found:
        _pose("pose", msg.pose)


def validate_map_update(msg: Any) -> None:
    if len(msg.keyframe_ids) != len(msg.keyframe_poses):
        raise MessageError(f"{len(msg.keyframe_ids)} keyframe ids but "
                           f"{len(msg.keyframe_poses)} poses")
    for i, pose in enumerate(msg.keyframe_poses):
        _pose(f"keyframe_poses[{i}]", pose)
    _pose("frame_correction", msg.frame_correction)
    n = len(msg.point_ids)
    if len(msg.point_positions) != 3 * n:
        raise MessageError(f"point_positions has {len(msg.point_positions)} values for {n} points")
    if len(msg.point_descriptors) != ORB_DESCRIPTOR_BYTES * n:
        raise MessageError(f"point_descriptors has {len(msg.point_descriptors)} bytes "
                           f"for {n} points")
    if len(msg.point_observations) not in (0, n):
        raise MessageError(f"point_observations has {len(msg.point_observations)} for {n} points")
    if n and not np.all(np.isfinite(msg.point_positions)):
        raise MessageError("point_positions hold non-finite values")
    if len(msg.keyframe_point_counts) not in (0, len(msg.keyframe_ids)) or \
            int(np.sum(msg.keyframe_point_counts, dtype=np.int64)) != len(msg.keyframe_point_ids):
        raise MessageError(f"keyframe_point_counts ({len(msg.keyframe_point_counts)} values) "
                           f"do not add up to the {len(msg.keyframe_point_ids)} keyframe point "
                           f"ids of {len(msg.keyframe_ids)} keyframes")
    if len(msg.track_ids) != len(msg.track_point_ids):
        raise MessageError(f"{len(msg.track_ids)} track ids but {len(msg.track_point_ids)} "
                           "track point ids")


def validate_uplink_throughput(msg: Any) -> None:
    for field in ("configured_rate_mbps", "achieved_mbps", "duration_s"):
        value = getattr(msg, field)
        _finite(field, value)
        if value < 0:
            raise MessageError(f"{field} must be >= 0, got {value}")


def validate_rate_latent(msg: Any) -> None:
    if len(msg.mu) != len(msg.sigma):
        raise MessageError(f"mu has {len(msg.mu)} values, sigma {len(msg.sigma)}")
    if len(msg.next_state_probs) != len(msg.state_rates_mbps):
        raise MessageError("next_state_probs and state_rates_mbps differ in length")
    probs = np.asarray(msg.next_state_probs, dtype=float)
    if probs.size and (not np.all(np.isfinite(probs)) or np.any(probs < 0)
                       or abs(probs.sum() - 1.0) > 1e-3):
        raise MessageError(f"next_state_probs is not a distribution: {probs}")
    if np.any(np.asarray(msg.sigma) < 0):
        raise MessageError("sigma holds a negative variance")


def validate_playback_pace(msg: Any) -> None:
    """A negative held time, or nanoseconds past a second, is no clock a camera stopped."""
    if not msg.camera:
        raise MessageError("a pace report names no camera")
    if msg.held.sec < 0 or not 0 <= msg.held.nanosec < 1_000_000_000:
        raise MessageError(f"held {msg.held.sec} s {msg.held.nanosec} ns is not a duration "
                           "a camera held")


VALIDATORS: dict[str, Callable[[Any], None]] = {
    "sensor_msgs/msg/Image": validate_image,
    "sensor_msgs/msg/CameraInfo": validate_camera_info,
    "geometry_msgs/msg/PoseStamped": validate_pose_stamped,
    "twinslam_msgs/msg/FrameSummaries": validate_frame_summaries,
    "twinslam_msgs/msg/UploadRequest": validate_upload_request,
    "twinslam_msgs/msg/Keyframe": validate_keyframe,
    "twinslam_msgs/msg/RelocalisationRequest": validate_relocalisation_request,
    "twinslam_msgs/msg/Relocalisation": validate_relocalisation,
    "twinslam_msgs/msg/MapUpdate": validate_map_update,
    "twinslam_msgs/msg/UplinkThroughput": validate_uplink_throughput,
    "twinslam_msgs/msg/RateLatent": validate_rate_latent,
    "twinslam_msgs/msg/PlaybackPace": validate_playback_pace,
}


def validate(type_name: str, msg: Any) -> None:
    """Run the validator registered for ``type_name`` (types without one are accepted)."""
    check = VALIDATORS.get(type_name)
    if check is not None:
        check(msg)
