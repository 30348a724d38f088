"""Dataset folders as sequences: SUN3D, 7-Scenes and TUM RGB-D behind one iterator.

Every reader yields :class:`RgbdFrame` (colour as RGB, depth in metres with 0 = no reading,
3×3 intrinsics, camera-to-world ground truth when the dataset has it) in capture order. A
corrupt or missing image is skipped, counted in ``skipped`` and named in a warning, so a long
replay survives one bad file; a missing folder or intrinsics file is a :class:`SequenceError`
naming the path, because nothing sensible can be replayed without it.

Layouts (as the datasets ship them):

* **SUN3D** — ``image/NNNNNNN-TTTTTTTTTTTT.jpg`` (frame number, timestamp in µs),
  ``depth/...png`` (16 bit, bit-rotated: mm = ((v >> 3) | (v << 13)) & 0xFFFF, paired with
  colour by nearest timestamp), ``intrinsics.txt`` (3×3), ``extrinsics/<YYYYMMDDhhmmss>.txt``
  (the newest file wins; three lines, a 3×4 camera-to-world, per colour frame; may be shorter
  than the image list — later frames then have no ground truth).
* **7-Scenes** — ``frame-XXXXXX.color.{jpg,png}``, ``frame-XXXXXX.depth.png`` (mm; 0 and 65535
  invalid), ``frame-XXXXXX.pose.txt`` (4×4 camera-to-world), ``camera-intrinsics.txt``;
  recorded at 30 Hz, so stamps are frame index / 30.
* **TUM RGB-D** — ``rgb.txt``/``depth.txt`` ("stamp path" lines), ``groundtruth.txt`` ("stamp
  tx ty tz qx qy qz qw"), associated by nearest stamp within 20 ms; depth PNGs scaled by 5000.
  Intrinsics from ``camera-intrinsics.txt`` or ``intrinsics.txt`` when present, else the
  published calibration of the freiburg1/2/3 sensor named in the folder.
"""

from __future__ import annotations

import bisect
import logging
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from twinslam.sequences.decoded_frames import DecodedFrameCache, Frame
from twinslam.sequences.frame import RgbdFrame, SequenceError, pose_from_xyzq
from twinslam.sequences.registration import camera_matrix, camera_placement, register_depth

log = logging.getLogger(__name__)

SEVEN_SCENES_HZ = 30.0
#: TUM RGB-D's association tolerance (its associate.py default).
TUM_MAX_DT = 0.02
TUM_DEPTH_SCALE = 5000.0
#: Published colour-camera calibrations of the TUM RGB-D sensors (fx, fy, cx, cy).
TUM_CALIBRATION = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}


@dataclass
class _Entry:
    stamp: float
    color: Path
    depth: Path | None
    pose: np.ndarray | None


@dataclass
class FolderSequence:
    """Frames of one sequence folder; iterate it (as often as needed) for :class:`RgbdFrame`.

    ``start``/``end`` select entries [start, end) of the listing (end < 0: to the end).
    """

    path: Path
    kind: str
    intrinsics: np.ndarray
    entries: list[_Entry]
    depth_decoder: str                                  #: "mm", "sun3d", "tum"
    skipped: list[str] = field(default_factory=list)    #: files skipped in the last pass
    #: the depth camera's intrinsics where they are not the colour camera's (``intrinsics``):
    #: each depth image is then registered to the colour camera as it is read
    depth_intrinsics: np.ndarray | None = None
    #: with ``depth_intrinsics``: the 4×4 transform from the depth camera's frame to the colour
    #: camera's (None: the same place, the baseline unknown)
    depth_to_colour: np.ndarray | None = None
    #: decoded frames kept on disk (:mod:`twinslam.sequences.decoded_frames`); None: every
    #: frame decoded as it is read
    cache: DecodedFrameCache | None = None

    def __len__(self) -> int:
        return len(self.entries)

    def select(self, start: int = 0, end: int = -1) -> FolderSequence:
        if start < 0 or (end >= 0 and end < start):
            raise SequenceError(f"{self.path}: bad frame range start={start} end={end}")
        stop = len(self.entries) if end < 0 else min(end, len(self.entries))
        return FolderSequence(self.path, self.kind, self.intrinsics, self.entries[start:stop],
                              self.depth_decoder, depth_intrinsics=self.depth_intrinsics,
                              depth_to_colour=self.depth_to_colour, cache=self.cache)

    def with_colour_camera(self, colour_intrinsics: np.ndarray,
                           depth_to_colour: np.ndarray | None = None) -> FolderSequence:
        """The same frames seen by a colour camera with ``colour_intrinsics`` (placed at
        ``depth_to_colour`` from the depth camera, a 4×4; None: at the same place), where the
        folder's intrinsics file is the depth camera's (7-Scenes): frames carry those
        intrinsics and depth registered to them (:mod:`twinslam.sequences.registration`)."""
        try:         # checked once here, not at the first frame a replay reaches
            k = camera_matrix(colour_intrinsics, "colour").copy()
            t = None if depth_to_colour is None else camera_placement(depth_to_colour).copy()
        except ValueError as exc:
            raise SequenceError(f"{self.path}: {exc}") from None
        depth_k = self.intrinsics if self.depth_intrinsics is None else self.depth_intrinsics
        return FolderSequence(self.path, self.kind, k, self.entries, self.depth_decoder,
                              depth_intrinsics=depth_k, depth_to_colour=t, cache=self.cache)

    @property
    def stamps(self) -> np.ndarray:
        return np.array([e.stamp for e in self.entries])

    @property
    def poses(self) -> list[np.ndarray | None]:
        return [e.pose for e in self.entries]

    def __iter__(self) -> Iterator[RgbdFrame]:
        self.skipped = []
        for i in range(len(self.entries)):
            frame = self.read(i)
            if frame is not None:
                yield frame

    def read(self, i: int) -> RgbdFrame | None:
        """Frame ``i`` of the listing; None (skipped, counted, warned) when it cannot be
        decoded. Any order: a scenario may play the sequence backwards."""
        entry = self.entries[i]
        made = self._made(entry)
        if made is None:
            return None
        return RgbdFrame(i, entry.stamp, made[0], made[1], self.intrinsics, entry.pose,
                         entry.color.name)

    def _made(self, entry: _Entry) -> Frame | None:
        """The entry decoded, or read back where the cache holds it."""
        key = None if self.cache is None else self._cache_key(entry)
        if self.cache is None or key is None:
            return self._decode(entry)
        return self.cache.fetch(key, lambda: self._decode(entry))

    def _decode(self, entry: _Entry) -> Frame | None:
        """The entry's colour as RGB and its depth in metres (registered to the colour camera
        where the cameras differ); None (skipped, counted, warned) when a file cannot be
        decoded."""
        color = cv2.imread(str(entry.color), cv2.IMREAD_COLOR)
        if color is None:
            self._skip(entry.color, "cannot decode the colour image")
            return None
        depth = None
        if entry.depth is not None:
            raw = cv2.imread(str(entry.depth), cv2.IMREAD_UNCHANGED)
            if raw is None or raw.dtype != np.uint16 or raw.shape != color.shape[:2]:
                self._skip(entry.depth, "cannot decode the 16-bit depth image "
                                        "(or its size differs from the colour image)")
                return None
            depth = decode_depth(raw, self.depth_decoder)
            if self.depth_intrinsics is not None:
                depth = register_depth(depth, self.depth_intrinsics, self.intrinsics,
                                       self.depth_to_colour)
        return cv2.cvtColor(color, cv2.COLOR_BGR2RGB), depth

    def _cache_key(self, entry: _Entry) -> str | None:
        """The entry's name in the cache (None: a file that cannot be read, which decoding
        then skips and names)."""
        cameras = [self.intrinsics, self.depth_intrinsics, self.depth_to_colour]
        try:
            files = [entry.color.read_bytes(),
                     b"" if entry.depth is None else entry.depth.read_bytes()]
        except OSError:
            return None
        return DecodedFrameCache.key([b"folder", *files, self.depth_decoder.encode()] + [
            b"-" if m is None else np.asarray(m, dtype=np.float64).tobytes() for m in cameras])

    def _skip(self, path: Path, why: str) -> None:
        self.skipped.append(str(path))
        log.warning("skipping %s: %s (%d skipped so far)", path, why, len(self.skipped))


def decode_depth(raw: np.ndarray, encoding: str) -> np.ndarray:
    """16-bit depth image → float32 metres, 0 where there is no reading."""
    v = raw.astype(np.uint32)
    if encoding == "sun3d":
        mm = ((v >> 3) | (v << 13)) & 0xFFFF
        return (mm.astype(np.float32) / 1000.0)
    if encoding == "tum":
        return (v.astype(np.float32) / TUM_DEPTH_SCALE)
    metres = v.astype(np.float32) / 1000.0
    metres[v == 0xFFFF] = 0.0               # 7-Scenes marks invalid pixels with 65535 too
    return metres


def read_matrix(path: Path, rows: int, cols: int) -> np.ndarray:
    """A whitespace-separated rows×cols matrix file, with a clear error when it is not one."""
    if not path.is_file():
        raise SequenceError(f"missing file {path}")
    try:
        m = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise SequenceError(f"{path}: not a numeric matrix ({exc})") from None
    if m.shape != (rows, cols) or not np.all(np.isfinite(m)):
        raise SequenceError(f"{path}: expected a finite {rows}×{cols} matrix, got {m.shape}")
    return m


# -- 7-Scenes ---------------------------------------------------------------------------------

_SEVEN = re.compile(r"frame-(\d+)\.color\.(jpg|png)$")


#: Microsoft 7-Scenes' colour camera (Kinect v1, 640×480): the dataset calibrates only its depth
#: camera (each scene's camera-intrinsics.txt, focal 585 px); its colour camera's focal is about
#: 525 px, the figure relocalisation work on 7-Scenes uses, the principal point at the centre
#: (config/7scenes-colour-intrinsics.txt holds the same matrix for the player's parameter)
SEVEN_SCENES_COLOUR_INTRINSICS = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0],
                                           [0.0, 0.0, 1.0]])
#: what every 7-Scenes scene's camera-intrinsics.txt holds: its depth camera's
SEVEN_SCENES_DEPTH_INTRINSICS = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0],
                                          [0.0, 0.0, 1.0]])


def read_seven_scenes(root: Path) -> FolderSequence:
    intrinsics = read_matrix(root / "camera-intrinsics.txt", 3, 3)
    entries = []
    for color in sorted(root.glob("frame-*.color.*")):
        match = _SEVEN.search(color.name)
        if not match:
            continue
        idx = int(match.group(1))
        depth = root / f"frame-{match.group(1)}.depth.png"
        pose_file = root / f"frame-{match.group(1)}.pose.txt"
        pose = None
        if pose_file.is_file():
            try:
                pose = read_matrix(pose_file, 4, 4)
            except SequenceError as exc:
                log.warning("no ground truth for %s: %s", color.name, exc)
        entries.append(_Entry(idx / SEVEN_SCENES_HZ, color, depth, pose))
    return FolderSequence(root, "7scenes", intrinsics, entries, "mm")


# -- SUN3D ------------------------------------------------------------------------------------

_SUN3D = re.compile(r"^(\d+)-(\d+)\.(jpg|png)$")


def _sun3d_listing(folder: Path) -> list[tuple[int, float, Path]]:
    out = []
    for p in folder.iterdir():
        match = _SUN3D.match(p.name)
        if match:
            out.append((int(match.group(1)), int(match.group(2)) * 1e-6, p))
    return sorted(out)


def read_sun3d(root: Path) -> FolderSequence:
    intrinsics = read_matrix(root / "intrinsics.txt", 3, 3)
    images = _sun3d_listing(root / "image")
    depth_dir = root / "depth"
    depths = _sun3d_listing(depth_dir) if depth_dir.is_dir() else []
    depth_stamps = [s for _, s, _ in depths]
    poses = _sun3d_extrinsics(root / "extrinsics")
    entries = []
    for i, (_, stamp, path) in enumerate(images):
        depth = None
        if depths:                          # nearest timestamp, as SUN3D's own loader pairs
            j = bisect.bisect_left(depth_stamps, stamp)
            near = min((k for k in (j - 1, j) if 0 <= k < len(depths)),
                       key=lambda k: abs(depth_stamps[k] - stamp))
            depth = depths[near][2]
        entries.append(_Entry(stamp, path, depth, poses[i] if i < len(poses) else None))
    return FolderSequence(root, "sun3d", intrinsics, entries, "sun3d")


def _sun3d_extrinsics(folder: Path) -> list[np.ndarray]:
    """Camera-to-world 4×4 per colour frame from the newest extrinsics file (may be short)."""
    files = sorted(folder.glob("*.txt")) if folder.is_dir() else []
    if not files:
        return []
    path = files[-1]
    try:
        values = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        log.warning("ignoring ground truth %s: %s", path, exc)
        return []
    if values.shape[1] != 4 or values.shape[0] % 3:
        log.warning("ignoring ground truth %s: expected 3×4 blocks, got %s", path, values.shape)
        return []
    poses = []
    for block in values.reshape(-1, 3, 4):
        pose = np.eye(4)
        pose[:3] = block
        poses.append(pose)
    return poses


# -- TUM RGB-D --------------------------------------------------------------------------------

def _tum_list(path: Path, columns: int) -> list[list[str]]:
    if not path.is_file():
        raise SequenceError(f"missing file {path}")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < columns:
            raise SequenceError(f"{path}:{number}: expected {columns} columns, got {len(parts)}")
        rows.append(parts)
    return rows


def _nearest(stamps: list[float], t: float, max_dt: float) -> int | None:
    j = bisect.bisect_left(stamps, t)
    best = None
    for k in (j - 1, j):
        if 0 <= k < len(stamps) and abs(stamps[k] - t) <= max_dt and (
                best is None or abs(stamps[k] - t) < abs(stamps[best] - t)):
            best = k
    return best


def _tum_intrinsics(root: Path) -> np.ndarray:
    for name in ("camera-intrinsics.txt", "intrinsics.txt"):
        if (root / name).is_file():
            return read_matrix(root / name, 3, 3)
    for sensor, (fx, fy, cx, cy) in TUM_CALIBRATION.items():
        if sensor in root.name:
            return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    raise SequenceError(f"{root}: no camera-intrinsics.txt and no freiburg1/2/3 in the folder "
                        "name to pick TUM's published calibration")


def read_tum(root: Path) -> FolderSequence:
    intrinsics = _tum_intrinsics(root)
    rgb = [(float(r[0]), root / r[1]) for r in _tum_list(root / "rgb.txt", 2)]
    depth_rows = [(float(r[0]), root / r[1]) for r in _tum_list(root / "depth.txt", 2)] \
        if (root / "depth.txt").is_file() else []
    depth_stamps = [t for t, _ in depth_rows]
    gt_rows = _tum_list(root / "groundtruth.txt", 8) if (root / "groundtruth.txt").is_file() \
        else []
    gt_stamps = [float(r[0]) for r in gt_rows]
    entries = []
    for stamp, path in sorted(rgb):
        d = _nearest(depth_stamps, stamp, TUM_MAX_DT)
        if depth_rows and d is None:
            continue                        # TUM's association drops unpaired colour frames
        g = _nearest(gt_stamps, stamp, TUM_MAX_DT)
        pose = pose_from_xyzq([float(x) for x in gt_rows[g][1:8]]) if g is not None \
            else None
        entries.append(_Entry(stamp, path, depth_rows[d][1] if d is not None else None, pose))
    return FolderSequence(root, "tum", intrinsics, entries, "tum")
