"""Options and specs several commands share: the covisibility data, the uplink's rate model and
range, V_max (the simulator and the trainer take the same setting)."""

from __future__ import annotations

import argparse
from pathlib import Path

from twinslam.common import table1
from twinslam.node_hosts.fastdds import REPO_ROOT
from twinslam.simulator.covisibility import (
    CovisibilityDataset,
    CovisibilityError,
    load_covisibility,
)
from twinslam.simulator.geometric_covisibility import geometric_covisibility

#: the uplink rate model when none is named: the paper's two-state Markov chain
DEFAULT_CHANNEL = "markov:N=2"


def covisibility(spec: str) -> CovisibilityDataset:
    """``FILE[@START:END]`` (a stretch of a covisibility file's frames) or
    ``geometric[:FRAMES[:SEED]]`` (the room model; each seed walks its own trajectory)."""
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


def rate_range(text: str) -> tuple[float, float]:
    """``--rate-range`` of sim and train: 'min,max' in Mbit/s."""
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'min,max', got {text!r}") from None
    return lo, hi


def add_setting_arguments(parser: argparse.ArgumentParser) -> None:
    """What the simulator and the trainer both take: the data, the uplink and V_max."""
    parser.add_argument("--covis", required=True, metavar="FILE[@START:END]|geometric[:N[:SEED]]",
                        help="covisibility .npz from `twinslam extract` (@START:END: only that "
                        "stretch of its frames, e.g. to hold the rest out), or "
                        "'geometric[:frames[:seed]]' for the geometric room model (600 frames, "
                        "seed 0 unless given; each seed walks its own trajectory)")
    parser.add_argument("--channel", default=DEFAULT_CHANNEL,
                        help="uplink rate model (default %(default)s). "
                        "markov:N=2[,ratio=R][,K=100][,nonstationary][,balanced]: N rates evenly "
                        "over --rate-range; ratio=R: share of high-rate slots (N=2); K: slots "
                        "per interval; nonstationary: a new matrix every K slots; balanced: "
                        "every state equally often. trace:FILE[,N=4][,states=MIN-MAX][,rescale]"
                        "[,start=S][,slot=S]: a CSV throughput trace at its real Mbit/s (an "
                        "outage uploads nothing), states by the trace's quantiles or evenly "
                        "over states=, rescale: map its min..max onto --rate-range, start: "
                        "seconds into the trace for every seed (default: an offset per seed), "
                        "slot: seconds a slot lasts (default 2)")
    parser.add_argument("--rate-range", type=rate_range, metavar="MIN,MAX",
                        default=f"{table1.RATE_MIN_MBPS:g},{table1.RATE_MAX_MBPS:g}",
                        help="Mbit/s the Markov channel's N rates spread over (a trace only "
                        "with its rescale option)")
    parser.add_argument("--vmax", type=int, default=table1.VMAX,
                        help="V_max, keyframes the edge map holds at most")


#: the 7-Scenes frames ../shared/data ships (the demo's and evaluate's default sequence)
BUNDLED_SEQUENCE = REPO_ROOT.parent / "shared" / "data" / "7scenes-1000"
#: the covisibility the ORB front end extracted from 1000 of them (shipped in data/)
BUNDLED_COVIS = REPO_ROOT / "data" / "7scenes-redkitchen-1000.covis.npz"
