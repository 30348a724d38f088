"""What the edge keeps of one device beside the map of its place.

A place's map — its keyframes, points, archive, bundle adjustment and loops — is the place's;
some of what a back end has always kept is the device's alone, and two devices sharing one
place's map (docs/architecture.md §10, "Devices in one place", step 2(b)) each need their own:

* its **slice** of the map (:class:`~twinslam.slam.back_end.keyframe_slice.KeyFrameSlice`):
  the keyframes it holds;
* its **local mapping** (:class:`~twinslam.slam.back_end.local_mapping.LocalMapping`): its
  camera and which map point each of its feature tracks became — track ids are the device's
  own numbering, and two devices' tracks 17 are different corners;
* **when each of its keyframes entered** its slice (the planner's "oldest",
  :mod:`twinslam.slot_protocol.map_entry`) and each one's **capture time** (its keyframe
  trajectory);
* **the map versions it was sent**, and the frame of each: loops and merges move the map
  under a device, and a keyframe it posed on an older version must be moved by what the map went
  through since (:meth:`DeviceRecord.in_current_frame`); and where its first camera is now
  (:attr:`DeviceRecord.origin`, the keyframe gate's reference).

This module keeps those together, with their checkpoint arrays, so that a place's back end can
hold one record a device.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Container, Mapping
from dataclasses import dataclass, field

import numpy as np

from twinslam.slam.back_end.foreign_keyframes import tag_of
from twinslam.slam.back_end.keyframe_slice import KeyFrameSlice
from twinslam.slam.back_end.local_mapping import LocalMapping
from twinslam.slam.camera import Camera
from twinslam.slam.keyframe import KeyFramePayload


@dataclass
class DeviceRecord:
    """One device's share of a place's back end (see the module's text)."""

    #: the keyframes of the place's map the device holds
    slice: KeyFrameSlice
    #: its keyframes into map edits, its camera, its tracks' map points
    local_mapping: LocalMapping
    #: the configured image size (with :attr:`k`, the device's :attr:`camera`)
    image_shape: tuple[int, int]
    #: when each keyframe of its slice entered it: (the slot that asked for it, UPLOADED) or
    #: (the slot that brought it back at its end, RESTORED) — changed in place, never
    #: replaced (the slot planner reads it)
    entered: dict[int, tuple[int, int]] = field(default_factory=dict)
    #: each of its integrated keyframes' capture time (s): its place in the trajectory
    keyframe_stamps: dict[int, float] = field(default_factory=dict)
    #: the applied loops' and merges' corrections at the walk's head, composed: the frame the
    #: map is in relative to the one the walk started in (MapUpdate.frame_correction)
    frame_correction: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: where the device's first camera — its map's origin until a merge moved the map into
    #: another device's frame — is now; loops hold it still
    origin: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: (first map version carrying it, frame_correction): the frame each version is in
    frames_since: list[tuple[int, np.ndarray]] = field(default_factory=list)
    #: the newest map version the device was sent (each device counts its own)
    version: int = 0
    #: the tag its keyframe ids carry in the place's map
    #: (:func:`~twinslam.slam.back_end.foreign_keyframes.foreign_tag`; 0: the place's first
    #: device, whose ids are its frame indices as they are)
    tag: int = 0

    def __post_init__(self) -> None:
        if not self.frames_since:
            self.frames_since = [(0, self.frame_correction.copy())]

    @classmethod
    def restored(cls, slice_: KeyFrameSlice, local_mapping: LocalMapping,
                 image_shape: tuple[int, int], arrays: Mapping[str, np.ndarray], tag: int = 0
                 ) -> DeviceRecord:
        """The record :meth:`checkpoint_arrays` wrote (``arrays``: a checkpoint's, or none:
        a fresh device) for the device of tag ``tag``."""
        def frame(name: str) -> np.ndarray:
            return np.asarray(arrays.get(name, np.eye(4)), dtype=np.float64).reshape(4, 4)

        stamps = dict(zip((int(k) for k in arrays.get("keyframe_stamp_ids", ())),
                          (float(t) for t in arrays.get("keyframe_stamps", ())), strict=True))
        entered = dict(zip(
            (int(k) for k in arrays.get("entered_ids", ())),
            ((int(s), int(p)) for s, p in zip(arrays.get("entered_slots", ()),
                                               arrays.get("entered_phases", ()), strict=True)),
            strict=True))
        return cls(slice_, local_mapping, image_shape, entered, stamps,
                   frame("frame_correction"), frame("origin"),
                   version=int(arrays.get("version", 0)), tag=tag)

    @property
    def k(self) -> np.ndarray:
        """The device's camera intrinsics (the identity until its first keyframe brings
        them)."""
        return self.local_mapping.k

    @k.setter
    def k(self, intrinsics: np.ndarray) -> None:
        self.local_mapping.k = np.asarray(intrinsics, dtype=np.float64)

    @property
    def camera(self) -> Camera:
        """The device's camera: :attr:`k` at the configured image size."""
        return Camera(self.k, self.image_shape)

    # -- the frame of each map version -------------------------------------------------------

    def frame_correction_at(self, version: int) -> np.ndarray:
        """The frame map version ``version`` was in (its ``frame_correction``)."""
        return next((c for first, c in reversed(self.frames_since) if first <= version),
                    self.frames_since[0][1])

    def moved_since(self, version: int) -> np.ndarray:
        """The motion the map's frame went through (loops, a merge) since map version
        ``version`` (-1: unknown, taken as now: the identity): a pose the device posed on that
        version, times it, is in the map's frame now."""
        if version < 0:
            return np.eye(4)
        return self.frame_correction @ np.linalg.inv(self.frame_correction_at(version))

    def in_current_frame(self, data: KeyFramePayload, tracked_on: int) -> KeyFramePayload:
        """A keyframe the device tracked against map version ``tracked_on`` (-1: unknown), in
        the frame the map is in now: a loop corrected since then did not reach the device
        before it posed this frame (the map update comes a slot or two after the slot that
        closed it), so its pose moves by the corrections applied since — else it would enter
        the corrected map where the uncorrected one had it, its points a second copy of the
        place."""
        since = self.moved_since(tracked_on)
        if np.allclose(since, np.eye(4), atol=1e-12):
            return data
        return dataclasses.replace(data, pose=since @ data.pose)

    def frame_moved(self, head: np.ndarray) -> None:
        """The map moved under the device by ``head`` (the correction at its walk's head),
        from its next map version on."""
        self.frame_correction = head @ self.frame_correction
        self.frames_since.append((self.version + 1, self.frame_correction.copy()))

    def owns(self, kf_id: int) -> bool:
        """Whether keyframe ``kf_id`` of the place is one the device uploaded (its tag)."""
        return tag_of(kf_id) == self.tag

    def head_of(self, corrections: Mapping[int, np.ndarray]) -> np.ndarray | None:
        """Of a loop's ``corrections`` (keyframe id → 4×4), the one at the device's walk's
        head — its newest keyframe the loop moved; every keyframe it posed since, and every
        pose it holds, needs that correction (None: the loop moved none of its keyframes)."""
        newest = max((k for k in corrections if self.owns(k)), default=None)
        return None if newest is None else corrections[newest]

    # -- checkpoint --------------------------------------------------------------------------

    def checkpoint_arrays(self, kept: Container[int]) -> dict[str, np.ndarray]:
        """What a restarted edge reads back of the device (:meth:`restored`): the map version
        it was sent last, the frame that map is in, where its first camera is, and — of the
        keyframes the place keeps (``kept``) — capture times, and when those in its slice
        entered it."""
        stamped = sorted(k for k in self.keyframe_stamps if k in kept)
        held = sorted(k for k in self.entered if self.slice.holds(k))
        return {"version": np.array(self.version),
                "frame_correction": self.frame_correction, "origin": self.origin,
                "keyframe_stamp_ids": np.array(stamped, dtype=np.int64),
                "keyframe_stamps": np.array([self.keyframe_stamps[k] for k in stamped],
                                            dtype=np.float64),
                "entered_ids": np.array(held, dtype=np.int64),
                "entered_slots": np.array([self.entered[k][0] for k in held], dtype=np.int64),
                "entered_phases": np.array([self.entered[k][1] for k in held],
                                           dtype=np.int64)}
