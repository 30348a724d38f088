"""The archive's pose file: where each archived keyframe stands now, where its own file was
written at another pose.

A loop's correction moves every archived keyframe behind the loop, its pose and its points by
one rigid motion each (:meth:`~twinslam.slam.back_end.keyframe_archive.KeyFrameArchive.
correct`), and a merge moves a joining map's whole archive. The archive's files must follow,
or a restarted edge (or a standby taking the device over) reads the places before the loop.
Each keyframe's file was written again for that: on an archive of 500 keyframes of the
7-Scenes walk, 500 files of ~90 KB and 500 fsyncs, 0.5–0.7 s of the loop closer's worker a loop
(``bench.loop_closer``) — on a disk slower to sync than this VM's, seconds a loop, for every
device an edge serves.

A keyframe's descriptors, measurements and point ids never move, and a correction moves its
points with its camera: the points relative to the camera are what the file holds already,
whatever the pose. So a correction is one small file: for each archived keyframe whose pose
is no longer its file's, the pose its file holds (and the slot that archived it), and the
pose it has now. Reading the archive back, a keyframe whose file still holds that pose is
moved by ``now · file⁻¹``, points with it; an entry whose file was written again since
(a keyframe restored and archived again) names a pose the file no longer holds and is left
out — the file is newer. The file is written whole (temporary name, fsync, rename), one of
at most the archive's capacity rows (4×4 twice a row: 256 bytes).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twinslam.npz_files import NPZ_READ_ERRORS, write_npz

POSES_FORMAT = "twinslam-archive-poses-1"
#: the pose file's name in the archive's folder
POSES_NAME = "poses.npz"


class PosesError(ValueError):
    """A pose file that cannot be read back."""


@dataclass(frozen=True)
class MovedPose:
    """Where an archived keyframe stands now, against where its file has it."""

    file_pose: np.ndarray        #: 4×4: the pose its file holds
    archived_slot: int           #: the slot its file says archived it
    pose: np.ndarray             #: 4×4: its pose now

    def matches(self, pose_on_file: np.ndarray, slot_on_file: int) -> bool:
        """Whether a file read back is the one this entry moves (not one written since)."""
        return slot_on_file == self.archived_slot and \
            np.array_equal(pose_on_file, self.file_pose)

    def motion(self) -> np.ndarray:
        """now · file⁻¹: the rigid motion that takes the file's keyframe where it is now."""
        return self.pose @ np.linalg.inv(self.file_pose)


def write_poses(path: Path, moved: Mapping[int, MovedPose]) -> None:
    """``moved`` written to ``path`` whole or not at all (temporary name, fsync, rename)."""
    ids = np.array(sorted(moved), dtype=np.int64)
    rows = [moved[k] for k in ids.tolist()]
    write_npz(path, {"format": np.array(POSES_FORMAT), "ids": ids,
                     "file_poses": np.array([m.file_pose for m in rows]).reshape(-1, 4, 4),
                     "archived_slots": np.array([m.archived_slot for m in rows],
                                                dtype=np.int64),
                     "poses": np.array([m.pose for m in rows]).reshape(-1, 4, 4)})


def read_poses(path: Path) -> dict[int, MovedPose]:
    """The entries of the pose file at ``path`` (none when there is no file); PosesError when
    it cannot be read."""
    if not path.exists():
        return {}
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["format"]) != POSES_FORMAT:
                raise PosesError(f"{path}: not a {POSES_FORMAT} file")
            ids, slots = z["ids"].astype(np.int64), z["archived_slots"].astype(np.int64)
            file_poses = z["file_poses"].astype(np.float64)
            poses = z["poses"].astype(np.float64)
    except NPZ_READ_ERRORS as exc:
        if isinstance(exc, PosesError):
            raise
        raise PosesError(f"{path}: not a readable pose file ({exc})") from None
    n = len(ids)
    if len(slots) != n or file_poses.shape != (n, 4, 4) or poses.shape != (n, 4, 4) or \
            not (np.isfinite(file_poses).all() and np.isfinite(poses).all()):
        raise PosesError(f"{path}: its arrays disagree in shape or hold non-finite poses")
    return {int(k): MovedPose(file_poses[i], int(slots[i]), poses[i])
            for i, k in enumerate(ids.tolist())}
