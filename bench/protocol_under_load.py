"""The slot protocol on a host with more work than cores: K two-device fleets (``twinslam
launch --loopback --devices 2 --merge-maps``) at once beside H busy loops, and what the nodes'
logs say of it — slots the edge closed on its timeout without the keyframes it asked for,
keyframes that came after their slot had closed (thrown away), slots whose upload request the
device waited for past its edge timeout, requested frames the device no longer held, camera
frames the devices skipped.

    python -m bench.protocol_under_load [--baseline COMMIT] [--fleets 4] [--busy 1]
                                        [--rounds 1] [--csv FILE]

A device whose tracking falls behind its camera must still answer the edge: its requests and
map updates are protocol, not frames. With ``--baseline`` each round runs the baseline's
fleets, then the working tree's, under the same load (the baseline checked out into a
temporary git worktree and run with this venv, as :mod:`bench.live` does).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.baseline import add_baseline_options, alternately
from bench.live import baseline_interfaces, tree_env
from bench.paths import REPO
from twinslam.reporting import write_dict_rows

#: what each count is, and the log text (a regular expression) that counts it
COUNTS = {
    "slots_closed": r"\] slot \d+: \+\d+ keyframes",
    "slots_timed_out": r"keyframe\(s\) did not arrive within",
    "keyframes_thrown_away": r"came twice or after its slot closed",
    "requests_waited_past_timeout": r"no upload request from the edge for",
    "requested_frames_no_longer_held": r"was asked for but is no longer held",
}


def busy_loop() -> subprocess.Popen[bytes]:
    """One process that keeps a core busy until killed."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def launch(root: Path, out: Path, frames: int, rate: float,
           extra_env: dict[str, str]) -> subprocess.Popen[str]:
    """One two-device fleet from checkout ``root``, its nodes' logs under ``out``."""
    cmd = [sys.executable, "-m", "twinslam.cli.main", "launch", "--loopback", "--devices",
           "2", "--merge-maps", "--sequence", f"synthetic:{frames}", "--frames", str(frames),
           "--orders", "forward,backward", "--rate", str(rate), "--out", str(out)]
    with (out.parent / f"{out.name}.stdout").open("w") as log:     # the child keeps its copy
        return subprocess.Popen(cmd, cwd=root, env=tree_env(root, extra_env), text=True,
                                stdout=log, stderr=subprocess.STDOUT)


def counted(out: Path) -> dict[str, int]:
    """The counts of :data:`COUNTS` in one fleet's nodes' logs, and the camera frames its
    devices skipped (each device's last "skipped so far")."""
    text = "\n".join(p.read_text(errors="replace") for p in sorted(out.glob("*.log")))
    row = {name: len(re.findall(pattern, text)) for name, pattern in COUNTS.items()}
    skipped: dict[str, int] = {}
    for device, n in re.findall(r"\[(\w+)\.device_tracker\]: slot \d+: .*?(\d+) skipped so far",
                                text):
        skipped[device] = int(n)
    row["camera_frames_skipped"] = sum(skipped.values())
    return row


def run_fleets(root: Path, folder: Path, fleets: int, busy: int, frames: int, rate: float,
               extra_env: dict[str, str]) -> list[dict[str, int]]:
    """``fleets`` fleets at once beside ``busy`` busy loops; each fleet's counts."""
    hogs = [busy_loop() for _ in range(busy)]
    try:
        outs = [folder / f"fleet{i + 1}" for i in range(fleets)]
        procs = [launch(root, out, frames, rate, extra_env) for out in outs]
        for proc in procs:
            proc.wait(timeout=1800)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    failed = [out for out, proc in zip(outs, procs, strict=True) if proc.returncode != 0]
    if failed:
        raise RuntimeError(f"launch failed: see {failed[0]}.stdout")
    return [counted(out) for out in outs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_baseline_options(parser, 1, "rounds, each the baseline's fleets then this tree's")
    parser.add_argument("--fleets", type=int, default=4,
                        help="two-device fleets run at once (default: 4)")
    parser.add_argument("--busy", type=int, default=1,
                        help="busy loops beside them, a core each (default: 1)")
    parser.add_argument("--frames", type=int, default=300,
                        help="frames of the synthetic room each device plays (default: 300)")
    parser.add_argument("--rate", type=float, default=0.5,
                        help="playback speed, x the recorded rate (default: 0.5)")
    parser.add_argument("--csv", type=Path, default=None,
                        help="write one row a fleet here (default: none)")
    args = parser.parse_args()
    print(f"machine: {platform.node()} {os.cpu_count()} cores, python "
          f"{platform.python_version()}; {args.fleets} fleets of 2 devices beside "
          f"{args.busy} busy loop(s), {args.frames} frames at {args.rate}x", flush=True)
    names = {"current": "current"}
    if args.baseline:
        names["baseline"] = "baseline " + subprocess.run(
            ["git", "rev-parse", "--short", args.baseline], cwd=REPO, check=True,
            capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="twinslam-protocol-load-") as tmp:
        envs: dict[str, dict[str, str]] = {"current": {}}
        rows: list[dict[str, object]] = []          # one a fleet, in the order they ran

        def measure(r: int, label: str, root: Path) -> None:
            if label not in envs:           # the baseline's own interfaces, if they differ
                envs[label] = baseline_interfaces(args.baseline, root, Path(tmp) / "msgs")
            folder = Path(tmp) / f"r{r + 1}-{label}"
            folder.mkdir()
            started = time.monotonic()
            fleets = run_fleets(root.resolve(), folder, args.fleets, args.busy, args.frames,
                                args.rate, envs[label])
            totals = {k: sum(f[k] for f in fleets) for k in fleets[0]}
            print(f"round {r + 1} {names[label]}: {time.monotonic() - started:.0f} s, "
                  + ", ".join(f"{k} {v}" for k, v in totals.items()), flush=True)
            rows.extend({"round": r + 1, "code": names[label], "fleet": i + 1, **f}
                        for i, f in enumerate(fleets))

        alternately(args.baseline, args.rounds, measure)
    if args.csv is not None and rows:
        write_dict_rows(args.csv, rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
