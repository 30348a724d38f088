"""``bench.view_overlap``: how much of one view two keyframes share, three ways — an image
and itself near 1 on each, a view 0.4 m and 30° away far less, corners that look like none of
the first's nothing — and the table of a run's CSV read back is the table the run printed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from bench.archive_pnp import room_archive
from bench.view_overlap import overlap, read_pairs, table
from twinslam.reporting import write_dict_rows
from twinslam.slam.camera import Camera


def test_a_view_shares_its_corners_less_the_further_the_camera_moved(tmp_path: Path) -> None:
    seq, archive = room_archive()
    camera = Camera(seq.intrinsics)                              # type: ignore[attr-defined]
    view = archive.get(60)
    same = overlap(view, dataclasses.replace(view, id=61), camera, near_m=0.02)
    assert same.apart_m == 0.0 and same.turned_deg < 0.1 and same.gap == 1
    assert min(same.matched, same.same_corner, same.welded) >= 0.9, same
    turned = overlap(view, archive.get(180), camera, near_m=0.02)
    assert turned.gap == 120 and turned.apart_m > 0.3 and turned.turned_deg > 20
    assert max(turned.matched, turned.same_corner, turned.welded) <= 0.2, turned
    noise = np.random.default_rng(0).integers(0, 256, view.descriptors.shape, dtype=np.uint8)
    unlike = overlap(view, dataclasses.replace(view, id=62, descriptors=noise), camera, 0.02)
    assert max(unlike.matched, unlike.same_corner, unlike.welded) <= 0.02, unlike
    printed = table([same, turned, unlike])
    assert printed[2].startswith("| 1 | 1 | 0.000 |") and printed[2].endswith("| 1 |")
    written = tmp_path / "pairs.csv"
    write_dict_rows(written, [dataclasses.asdict(p) for p in (same, turned, unlike)])
    assert table(read_pairs(written)) == printed
