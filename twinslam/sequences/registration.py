"""Depth images moved into the colour camera: what a sequence whose two cameras differ needs.

A tracker reads the depth of a colour keypoint at the keypoint's pixel. That is right only
when the depth image is *registered* — taken, or re-projected, as the colour camera sees the
scene. TUM RGB-D and SUN3D ship registered depth; 7-Scenes does not: its frames are the
Kinect's raw images, its ``camera-intrinsics.txt`` is the depth camera's (focal 585 px) and
its colour camera's focal is about 525 px (the figure relocalisation work on 7-Scenes uses).
Tracked with 585 for both, a keypoint 300 px from the centre is back-projected 10 % too close
to the axis and reads the depth of another point: the map is squashed sideways and bent
where the depth changes. Registering each depth image to the colour camera removes both.

The registration is the standard forward warp: each depth pixel is back-projected with the
depth camera's intrinsics, moved by the depth-to-colour transform (identity where the
baseline is not known) and projected with the colour camera's; where several readings land
on one colour pixel the nearest is kept (a z-buffer: the surface in front hides the one
behind); colour pixels no reading lands on have no depth (0).
"""

from __future__ import annotations

import numpy as np

from twinslam.kernel_cache import njit


def register_depth(depth: np.ndarray, depth_intrinsics: np.ndarray,
                   colour_intrinsics: np.ndarray,
                   depth_to_colour: np.ndarray | None = None) -> np.ndarray:
    """``depth`` (metres, 0 = no reading, H×W) of the camera with ``depth_intrinsics`` as
    the colour camera with ``colour_intrinsics`` sees it, same size and dtype; the optional
    4×4 ``depth_to_colour`` takes a point from the depth camera's frame to the colour
    camera's."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"a depth image is H×W, got shape {depth.shape}")
    kd = camera_matrix(depth_intrinsics, "depth")
    kc = camera_matrix(colour_intrinsics, "colour")
    floats = np.ascontiguousarray(depth if depth.dtype in (np.float32, np.float64)
                                  else depth.astype(np.float64))
    if depth_to_colour is None:
        h, w = depth.shape
        nearest = _warp_by_row_and_column(floats,
                                          _target_lines(w, kd[0, 0], kd[0, 2], kc[0, 0], kc[0, 2]),
                                          _target_lines(h, kd[1, 1], kd[1, 2], kc[1, 1], kc[1, 2]))
    else:
        t = camera_placement(depth_to_colour)
        nearest = _forward_warp(floats, kd, kc, np.ascontiguousarray(t[:3, :3]),
                                np.ascontiguousarray(t[:3, 3]))
    return nearest.astype(depth.dtype, copy=False)


def _target_lines(n: int, f_depth: float, c_depth: float, f_colour: float,
                  c_colour: float) -> np.ndarray:
    """Where each of ``n`` columns (or rows) of the depth image lands in the colour image when
    both cameras sit at one place: back-projected at depth z and projected again, z cancels,
    so a column goes to one column whatever its readings (-1: outside the image)."""
    lines = np.arange(n, dtype=np.float64)
    target = np.rint(f_colour * ((lines - c_depth) / f_depth) + c_colour)
    return np.where((target >= 0) & (target < n), target, -1).astype(np.int64)


@njit(cache=True)
def _warp_by_row_and_column(depth: np.ndarray, columns: np.ndarray,
                            rows: np.ndarray) -> np.ndarray:
    """The warp of :func:`register_depth` without a baseline: every reading goes to the pixel
    its row and column map to, the nearest kept (the per-pixel projection of
    :func:`_forward_warp` took a fifth of the player's time on 7-Scenes)."""
    h, w = depth.shape
    nearest = np.zeros((h, w), dtype=depth.dtype)
    for v in range(h):
        iv = rows[v]
        if iv < 0:
            continue
        for u in range(w):
            iu = columns[u]
            z = depth[v, u]
            if iu < 0 or not z > 0:
                continue
            if nearest[iv, iu] == 0.0 or z < nearest[iv, iu]:
                nearest[iv, iu] = z
    return nearest


@njit(cache=True)
def _forward_warp(depth: np.ndarray, kd: np.ndarray, kc: np.ndarray, rotation: np.ndarray,
                  translation: np.ndarray) -> np.ndarray:
    """The warp of :func:`register_depth` across a baseline, one pass over the pixels in
    float64 whatever the depth's float type (the array form — back-project all, project all,
    ``np.minimum.at`` — took 22 ms a 640×480 frame, most of the player's time on 7-Scenes)."""
    h, w = depth.shape
    nearest = np.zeros((h, w), dtype=depth.dtype)
    for v in range(h):
        for u in range(w):
            z = np.float64(depth[v, u])
            if not z > 0:
                continue
            x = (u - kd[0, 2]) / kd[0, 0] * z
            y = (v - kd[1, 2]) / kd[1, 1] * z
            x, y, z = (rotation[0, 0] * x + rotation[0, 1] * y + rotation[0, 2] * z
                       + translation[0],
                       rotation[1, 0] * x + rotation[1, 1] * y + rotation[1, 2] * z
                       + translation[1],
                       rotation[2, 0] * x + rotation[2, 1] * y + rotation[2, 2] * z
                       + translation[2])
            if not z > 0:
                continue
            uc = np.rint(kc[0, 0] * x / z + kc[0, 2])
            vc = np.rint(kc[1, 1] * y / z + kc[1, 2])
            if not (0 <= uc < w and 0 <= vc < h):
                continue
            iu, iv = int(uc), int(vc)
            if nearest[iv, iu] == 0.0 or z < nearest[iv, iu]:
                nearest[iv, iu] = z          # rounded to the depth's type: the same order
    return nearest


def camera_matrix(k: np.ndarray, camera: str) -> np.ndarray:
    """``k`` as a float 3×3 intrinsics matrix; ValueError naming the ``camera`` unless it is
    finite with positive focal lengths."""
    m = np.asarray(k, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)) or m[0, 0] <= 0 or m[1, 1] <= 0:
        raise ValueError(f"the {camera} camera's intrinsics must be a finite 3×3 matrix with "
                         f"positive focal lengths, got {m.tolist()}")
    return m


def camera_placement(t: np.ndarray) -> np.ndarray:
    """``t`` as a float 4×4 depth-to-colour transform; ValueError unless it is a finite one."""
    m = np.asarray(t, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"the depth-to-colour transform must be a finite 4×4 matrix, got "
                         f"shape {m.shape}")
    return m
