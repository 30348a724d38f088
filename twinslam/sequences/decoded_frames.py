"""A disk cache of decoded dataset frames and rendered synthetic ones, for sequences that are
played again and again.

Decoding is most of what the sequence player spends on a dataset frame: on the 7-Scenes sample
the depth PNG, the colour JPEG, the depth's conversion to metres and its registration to the
colour camera take about two thirds of the player's CPU (py-spy, a 400-frame live run), and
on a 2-core host that CPU is taken from the device the player feeds; a synthetic world's frame
takes ~10 ms to ray-cast. An evaluation plays the same frames for every scenario, policy and
seed, so with ``TWINSLAM_FRAME_CACHE`` set each frame is made once and read back as arrays
from then on (about a fifth of the CPU).

An entry is named by a SHA-256 of what decides its pixels: for a dataset frame the bytes of
its colour and depth files (~0.2 ms a 7-Scenes frame, so a file rewritten in place is never
answered from a stale entry, whatever its timestamps say), the depth decoding and the
registration's cameras; for a frame of a synthetic world (:mod:`twinslam.sequences.synthetic`)
the renderer's source, the world's textures and box, the camera and its pose. A frame is
written to a temporary file and renamed into place, so processes that play one sequence at
once (a fleet, the test suite's workers) share the cache without locks; an entry that cannot
be read back whole is removed and the frame made again; a temporary file a killed writer left
behind is removed by the next process that stores, once it is ten minutes old. The cache stops
growing at its size bound (``TWINSLAM_FRAME_CACHE_GB``, default 8): it never evicts, and
frames beyond it are made every time, as without a cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import tempfile
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from twinslam.sequences.frame import SequenceError

log = logging.getLogger(__name__)

#: the directory of the cache; unset or empty: no cache
CACHE_ENV = "TWINSLAM_FRAME_CACHE"
#: the cache's size bound in GB (10⁹ bytes)
BOUND_ENV = "TWINSLAM_FRAME_CACHE_GB"
DEFAULT_BOUND_GB = 8.0
#: what an entry holds and how; a change of it names every entry anew
FORMAT = b"twinslam decoded frame v1"
SUFFIX = ".frame.npy"
#: an entry being written, renamed to its ``SUFFIX`` name once whole
PARTIAL = ".partial"
#: a temporary file this old was left by a writer that was killed: removed
STALE_PARTIAL_S = 600.0
#: a frame's pixels: RGB colour and, where it has one, depth in metres
Frame = tuple[np.ndarray, np.ndarray | None]


class DecodedFrameCache:
    """Decoded frames (RGB colour, depth in metres) under ``root``, at most ``max_bytes``."""

    def __init__(self, root: Path, max_bytes: int) -> None:
        self.root = root
        self.max_bytes = max_bytes
        self._used: int | None = None          #: bytes held, counted at the first store
        self._full_said = False
        self._unwritable = False               #: a store failed: said once, not tried again

    @classmethod
    def from_environment(cls) -> DecodedFrameCache | None:
        """The cache ``TWINSLAM_FRAME_CACHE`` names (None where it is unset); a bound that is
        not a size is a :class:`SequenceError`, not a silent default."""
        root = os.environ.get(CACHE_ENV, "")
        if not root:
            return None
        bound = os.environ.get(BOUND_ENV, "") or str(DEFAULT_BOUND_GB)
        try:
            gigabytes = float(bound)
        except ValueError:
            raise SequenceError(f"{BOUND_ENV}={bound!r}: a size in GB expected") from None
        if not gigabytes >= 0:
            raise SequenceError(f"{BOUND_ENV}={bound!r}: a size in GB expected")
        return cls(Path(root), int(gigabytes * 1e9))

    @staticmethod
    def key(parts: Iterable[bytes]) -> str:
        """The entry of a frame whose pixels ``parts`` decide (a reader's whole input: the
        files' bytes and its settings, or a renderer's code and scene)."""
        digest = hashlib.sha256(FORMAT)
        for part in parts:
            digest.update(len(part).to_bytes(8, "little"))
            digest.update(part)
        return digest.hexdigest()

    def _path(self, key: str) -> Path:
        return self.root / f"{key}{SUFFIX}"

    def fetch(self, key: str, make: Callable[[], Frame | None]) -> Frame | None:
        """The frame under ``key``: read back where the cache holds it, else made by ``make``
        and kept (None where ``make`` could not make it: nothing is kept)."""
        cached = self.load(key)
        if cached is not None:
            return cached
        made = make()
        if made is not None:
            self.store(key, *made)
        return made

    def load(self, key: str) -> Frame | None:
        """(colour, depth) of the entry, or None where there is none or it is not whole."""
        path = self._path(key)
        try:
            fh = path.open("rb")
        except OSError:                  # none yet (a cache that cannot be had: store says so)
            return None
        try:
            with fh:
                color = np.load(fh, allow_pickle=False)
                has_depth = bool(np.load(fh, allow_pickle=False))
                depth = np.load(fh, allow_pickle=False) if has_depth else None
        except (OSError, ValueError, EOFError) as exc:
            log.warning("frame cache entry %s unreadable (%s): decoding the frame again",
                        path, exc)
            _remove(path)
            return None
        if not _well_formed(color, depth):
            log.warning("frame cache entry %s holds arrays of the wrong kind: decoding the "
                        "frame again", path)
            _remove(path)
            return None
        return color, depth

    def store(self, key: str, color: np.ndarray, depth: np.ndarray | None) -> None:
        """Keep the frame under ``key`` unless the cache is at its bound (or cannot be
        written: the frame was decoded and the run goes on without the entry)."""
        if self._unwritable:
            return
        size = color.nbytes + (0 if depth is None else depth.nbytes) + 384
        try:
            if self._used is None:                 # once a process, not once a frame
                self.root.mkdir(parents=True, exist_ok=True)
                self._used = self._scan()
            if self._used + size > self.max_bytes:
                if not self._full_said:
                    log.info("frame cache %s is at its %.1f GB bound: frames not in it are "
                             "decoded every time", self.root, self.max_bytes / 1e9)
                    self._full_said = True
                return
            fd, tmp = tempfile.mkstemp(dir=self.root, suffix=PARTIAL)
            try:
                with os.fdopen(fd, "wb") as fh:
                    np.save(fh, color, allow_pickle=False)
                    np.save(fh, np.array(depth is not None), allow_pickle=False)
                    if depth is not None:
                        np.save(fh, depth, allow_pickle=False)
                os.replace(tmp, self._path(key))
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError as exc:              # said once: a run's every frame would say it again
            log.warning("frame cache %s not written (%s): frames are made every time",
                        self.root, exc)
            self._unwritable = True
            return
        self._used += size

    def _scan(self) -> int:
        """Bytes the entries hold; on the way, the temporary files of writers killed before
        their rename (a frame's worth each, never read) are removed once they are
        ``STALE_PARTIAL_S`` old — a live writer renames its file within milliseconds."""
        used = 0
        now = time.time()
        for entry in os.scandir(self.root):
            if entry.name.endswith(SUFFIX):
                used += entry.stat().st_size
            elif entry.name.endswith(PARTIAL):
                with contextlib.suppress(OSError):     # another process may take it first
                    if now - entry.stat().st_mtime > STALE_PARTIAL_S:
                        os.unlink(entry.path)
        return used


def _remove(path: Path) -> None:
    """Remove a broken entry (another process may have replaced or removed it already)."""
    with contextlib.suppress(OSError):
        path.unlink()


def _well_formed(color: np.ndarray, depth: np.ndarray | None) -> bool:
    """An RGB uint8 image and, where there is one, a float32 depth image of its size."""
    if color.dtype != np.uint8 or color.ndim != 3 or color.shape[2] != 3:
        return False
    return depth is None or (depth.dtype == np.float32 and depth.shape == color.shape[:2])
