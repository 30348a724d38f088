"""Options and specs several commands share: the covisibility data, the uplink's rate model and
range, V_max (the simulator and the trainer take the same setting)."""

from __future__ import annotations

import argparse

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.hosts.fastdds import REPO_ROOT
from twinslam.simulator.covisibility_spec import open_covisibility
from twinslam.slot_protocol import table1
from twinslam.sweeps import EXECUTORS, Executor, make_executor

#: the uplink rate model when none is named: the paper's two-state Markov chain
DEFAULT_CHANNEL = "markov:N=2"


def covisibility(spec: str) -> CovisibilityDataset:
    """``FILE[@START:END]`` (a stretch of a covisibility file's frames) or
    ``geometric[:FRAMES[:SEED]]`` (the room model; each seed walks its own trajectory)."""
    return open_covisibility(spec)


def rate_range(text: str) -> tuple[float, float]:
    """``--rate-range`` of sim and train: 'min,max' in Mbit/s."""
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be 'min,max', got {text!r}") from None
    return lo, hi


#: the device's camera backlog, msg_schemas.qos.CAMERA's depth (importing it loads rclpy, which
#: a command line that only parses should not; a test holds the two equal): a window at it
#: paces nothing
_CAMERA_BACKLOG = 150


def pace_frames(text: str) -> int:
    """``--pace``: 0 (real time) or a window below the device's camera backlog."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number of frames, got {text!r}"
                                         ) from None
    if not 0 <= value < _CAMERA_BACKLOG:
        raise argparse.ArgumentTypeError(f"must be 0 (real time) to {_CAMERA_BACKLOG - 1} "
                                         f"frames (the device drops frames past "
                                         f"{_CAMERA_BACKLOG}), got {value}")
    return value


def add_pace_argument(parser: argparse.ArgumentParser) -> None:
    """``--pace`` of the commands that play live runs (launch, evaluate)."""
    parser.add_argument("--pace", type=pace_frames, default=0, metavar="FRAMES",
                        help="the camera waits for its device: at most FRAMES published frames "
                        "are left for the device to pose, a player holding its next frame while "
                        "that many are, the recording's clock stopped meanwhile, so a device "
                        "slower than real time on this machine tracks every frame instead of "
                        "dropping them "
                        "(what depends on the wall clock — the uplink, the edge's answers — "
                        "then sees slots that last longer); with --devices, every device's "
                        "camera waits while any device is behind (one recording clock: the "
                        "walks meet when the recording has them meet); 0: real time; default "
                        "%(default)s")


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
#: what the demo and evaluate play when that folder is missing: the synthetic world where the
#: edge's map decides tracking (twinslam.sequences.synthetic_worlds)
FALLBACK_SEQUENCE = "synthetic-corridor"
#: the covisibility the ORB front end extracted from 1000 of them (shipped in data/)
BUNDLED_COVIS = REPO_ROOT / "data" / "7scenes-redkitchen-1000.covis.npz"


def add_executor_arguments(parser: argparse.ArgumentParser, unit: str) -> None:
    """``--executor``, ``--jobs`` and ``--ray-address``: where a sweep's ``unit``s run."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help=f"where the {unit}s run: local (this machine's worker processes, "
                        "--jobs at a time; default) or ray (Ray tasks: a Ray started on this "
                        "machine with --jobs CPUs, or the cluster at --ray-address); the same "
                        "seeds give the same numbers on either")
    parser.add_argument("--jobs", type=int, default=None, metavar="N",
                        help=f"local: {unit}s at a time in worker processes, one torch thread "
                        "each (default 1: in this process); ray without --ray-address: the "
                        "CPUs of the Ray started here (default all)")
    parser.add_argument("--ray-address", default=None, metavar="ADDR",
                        help="with --executor ray: join this Ray cluster (host:port as `ray "
                        "start --head` printed it, ray://host:10001, or auto) instead of "
                        "starting one; every node needs twinslam installed and the data files "
                        "at the same paths")


def open_executor(args: argparse.Namespace) -> Executor:
    """The executor ``args`` ask for (a bad combination or an unreachable Ray raises
    ValueError / RuntimeError, each saying which option)."""
    return make_executor(args.executor, args.jobs, args.ray_address)
