"""A covisibility dataset named by a spec string — ``FILE[@START:END]`` (a stretch of a
covisibility file's frames) or ``geometric[:FRAMES[:SEED]]`` (the room model) — so that a
sweep's tasks carry a few bytes naming their data rather than the data (tens of MB pickled),
and each worker loads it once."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from twinslam.covisibility.dataset import (
    CovisibilityDataset,
    CovisibilityError,
    load_covisibility,
)
from twinslam.covisibility.geometric import geometric_covisibility


def open_covisibility(spec: str) -> CovisibilityDataset:
    """The dataset ``spec`` names (:mod:`this module <twinslam.simulator.covisibility_spec>`);
    a bad spec or file is a :class:`CovisibilityError` that says which."""
    if spec.startswith("geometric"):
        parts = spec.split(":")[1:]
        try:
            frames = int(parts[0]) if parts and parts[0] else 600
            seed = int(parts[1]) if len(parts) > 1 else 0
        except ValueError:
            raise CovisibilityError(f"--covis {spec!r}: use geometric[:FRAMES[:SEED]]") from None
        return geometric_covisibility(n_frames=frames, seed=seed)
    path, at, stretch = spec.partition("@")
    data = load_covisibility(Path(path))
    if not at:
        return data
    start, colon, end = stretch.partition(":")
    try:
        if not colon:
            raise ValueError
        return data.stretch(int(start or 0), int(end) if end else data.n_frames)
    except ValueError as exc:
        if isinstance(exc, CovisibilityError):
            raise
        raise CovisibilityError(f"--covis {spec!r}: use FILE@START:END (frame indices)") from None


def absolute_spec(spec: str) -> str:
    """``spec`` with its file made absolute, so a worker in another directory finds it."""
    if spec.startswith("geometric"):
        return spec
    path, at, stretch = spec.partition("@")
    return f"{Path(path).resolve()}{at}{stretch}"


@lru_cache(maxsize=4)
def cached_covisibility(spec: str) -> CovisibilityDataset:
    """:func:`open_covisibility`, once per worker process and spec."""
    return open_covisibility(spec)
