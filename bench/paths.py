"""Where the benchmarks find the checkout and the data beside it: one place, so that every
bench's default sequence is the same bundled sample (``../shared`` next to the checkout, as
CI and the README lay it out)."""

from __future__ import annotations

from pathlib import Path

#: the checkout
REPO = Path(__file__).resolve().parents[1]
#: the bundled 7-Scenes sample (1000 frames of redkitchen), the benches' default sequence
SEVEN_SCENES = REPO.parent / "shared" / "data" / "7scenes-1000"
