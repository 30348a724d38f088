"""Where the tests find the bundled RGB-D samples, and what they run on without them.

``../shared/data`` (or ``$TWINSLAM_SHARED_DATA``) holds a 7-Scenes and a SUN3D sample. A test
of the live pipeline or the front end runs on the 7-Scenes sample when it is there and on the
rendered synthetic room otherwise, so a checkout without the data still exercises every node;
only tests of a dataset's own file format (and of data derived from it) need the sample.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TWINSLAM_SHARED_DATA") or REPO.parent / "shared" / "data")
SEVEN = SHARED_DATA / "7scenes-1000"
SUN3D = SHARED_DATA / "sun3d-mit_w85k1-whole_apartment-30"
HAVE_SEVEN = SEVEN.is_dir()

needs_seven = pytest.mark.skipif(not HAVE_SEVEN, reason=f"tests the 7-Scenes sample's format "
                                 f"or data derived from it; absent: {SEVEN}")
needs_sun3d = pytest.mark.skipif(not SUN3D.is_dir(), reason=f"tests the SUN3D sample's format; "
                                 f"absent: {SUN3D}")


def seven_or_synthetic(frames: int = 1000) -> str:
    """The 7-Scenes sample when present, else ``frames`` frames of the synthetic room."""
    return str(SEVEN) if HAVE_SEVEN else f"synthetic:{frames}"
