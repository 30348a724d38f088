"""Arrays on disk (``.npz``) that a crash never leaves half written, and that read back with a
clear error however they were damaged.

The edge's map checkpoints, its archived keyframes and their pose file must survive an edge
killed at any moment: each is written to a temporary name, flushed to the disk and renamed
over the old file (:func:`write_npz`), so a reader finds the old file or the new one, whole.

A file can still be damaged after it was written — a disk fault, a copy cut short, a folder
put together by hand. ``np.load`` then fails in more ways than ``OSError`` and ``ValueError``:
a cut zip raises ``zipfile.BadZipFile`` ("File is not a zip file"), a flipped bit in a member
``zipfile.BadZipFile`` ("Bad CRC-32"), a damaged compressed member ``zlib.error``. A reader that
catches :data:`NPZ_READ_ERRORS` turns each into its own clear error instead of a traceback
that stops the edge.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: what reading a damaged ``.npz`` (or a missing member of one) raises
NPZ_READ_ERRORS: tuple[type[Exception], ...] = (
    OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def write_npz(path: Path, arrays: Mapping[str, Any]) -> None:
    """``arrays`` written to ``path`` whole or not at all: to a temporary name beside it,
    flushed to the disk, then renamed over the old file (``Any``: numpy's stubs would match
    an array's name to ``allow_pickle``)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    tmp.replace(path)
