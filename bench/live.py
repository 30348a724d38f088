"""The live pipeline (``twinslam launch --loopback``: player, device, edge as processes) on two
commits side by side, alternating in one run: the edge's compute ms per slot (median of its
MapStats, as the launch table prints it) and the device process's CPU ms per frame in steady
state (user + system time between the edge's first and last slot status lines, over the
frames of the slots in between; start-up and warm-up left out).

    python -m bench.live [--baseline COMMIT] [--rounds 3] [--frames 600] [--policy adapt]

The baseline is checked out into a temporary git worktree and run with this venv (its
dependencies are a subset of today's); each round runs the baseline, then the working tree.
When the baseline's ``.msg`` files differ from today's, its interface package is built
(rosidl, as ``make`` does) into a prefix of its own that only the baseline's runs load.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench.paths import REPO, SEVEN_SCENES
from twinslam.node_runtime.thread_cpu import stat_cpu

SEQUENCE = SEVEN_SCENES


def _device_cpu_s(root: Path) -> float | None:
    """CPU seconds of the newest running device process started from ``root`` (None if
    none)."""
    found: list[tuple[int, float]] = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            # started anew (``-m device_tracker.node``) or forked from the launcher's fork
            # server, which names its child after the node (``twinslam.hosts.forked``)
            forked = Path(f"/proc/{pid}/comm").read_text().strip() == "device_tracker"
            if (b"device_tracker.node" not in cmd and not forked) or \
                    Path(f"/proc/{pid}/cwd").resolve() != root:
                continue
            _, fields, cpu = stat_cpu(Path(f"/proc/{pid}/stat").read_text())
            found.append((int(fields[19]), cpu))
        except (OSError, IndexError, ValueError):
            continue
    return max(found)[1] if found else None


def build_interfaces(root: Path, prefix: Path) -> dict[str, str]:
    """Build checkout ``root``'s twinslam_msgs into ``prefix``; the environment its processes
    need to load that build instead of the venv's."""
    venv = Path(sys.executable).parent.parent
    build = prefix.parent / "msgs-build"
    build.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PATH=f"{venv / 'bin'}:{os.environ['PATH']}",
               AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv))
    print(f"building the baseline's interface package into {prefix} (its .msg files differ)",
          flush=True)
    subprocess.run(["cmake", str(root / "msg_schemas"), f"-DCMAKE_INSTALL_PREFIX={prefix}",
                    f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"],
                   cwd=build, env=env, check=True, capture_output=True)
    subprocess.run(["make", "-j2", "install"], cwd=build, env=env, check=True,
                   capture_output=True)
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" \
        / "site-packages"
    return {"PYTHONPATH": str(site), "LD_LIBRARY_PATH": str(prefix / "lib"),
            "AMENT_PREFIX_PATH": str(prefix)}


def baseline_interfaces(baseline: str, root: Path, prefix: Path) -> dict[str, str]:
    """The environment a process of the ``baseline`` commit checked out at ``root`` needs: its
    own twinslam_msgs built into ``prefix`` where its messages differ from the working tree's,
    nothing where they are the same (:func:`build_interfaces`)."""
    same = subprocess.run(["git", "diff", "--quiet", baseline, "--", "msg_schemas/msg"],
                          cwd=REPO).returncode == 0
    return {} if same else build_interfaces(root, prefix)


def tree_env(root: Path, extra_env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a process run from checkout ``root``: ``root`` first on the path,
    then ``extra_env``'s paths put before the inherited ones (a baseline's own interface
    build, :func:`build_interfaces`)."""
    env = dict(os.environ, PYTHONPATH=str(root), PYTHONUNBUFFERED="1")
    for key, value in (extra_env or {}).items():     # the checkout itself stays first
        first, then = (env.get(key, ""), value) if key == "PYTHONPATH" else (value,
                                                                             env.get(key, ""))
        env[key] = ":".join(v for v in (first, then) if v)
    return env


def run(root: Path, frames: int, policy: str, extra_env: dict[str, str] | None = None
        ) -> dict[str, float]:
    """One ``twinslam launch`` from checkout ``root``; its edge ms and device CPU ms/frame.
    ``extra_env``: paths put before the inherited ones (a baseline's own interface build)."""
    env = tree_env(root, extra_env)
    # the command line moved under the project package: older baselines have it
    # as a top-level package
    cli = "twinslam_cli.main" if (root / "twinslam_cli").is_dir() else "twinslam.cli.main"
    cmd = [sys.executable, "-m", cli, "launch", "--loopback", "--sequence",
           str(SEQUENCE), "--frames", str(frames), "--policy", policy]
    proc = subprocess.Popen(cmd, cwd=root, env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    latest: list[float] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            cpu = _device_cpu_s(root)
            if cpu is not None:
                latest.append(cpu)
            time.sleep(0.05)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    marks: list[tuple[int, float]] = []          # (slot, device CPU s) at each status line
    lines = []
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line)
        match = re.search(r"\] slot\s+(\d+) \|", line)
        if match and latest:
            marks.append((int(match[1]), latest[-1]))
    proc.wait(timeout=900)
    stop.set()
    watcher.join()
    out = "".join(lines)
    row = next((line for line in out.splitlines() if line.startswith(policy + " ")), None)
    if proc.returncode != 0 or row is None or len(marks) < 2:
        raise RuntimeError(f"launch in {root} failed ({proc.returncode}): {out[-3000:]}")
    (first, cpu0), (last, cpu1) = marks[0], marks[-1]
    slot_frames = frames // (max(s for s, _ in marks) + 1)
    values = re.split(r"\s+", row.strip())
    # newer tables carry RPE, failures, relocalisations and recovery after ATE, and
    # later a "υ tracked" column before ATE
    header = next((line for line in out.splitlines() if line.startswith("policy ")), "")
    ate = 4 if "υ tracked" in header else 3
    untracked = values[ate + 5] if "untrk" in header else values[-2]
    # newer tables end with the camera frames the device dropped after the edge's ms, the
    # newest with the slots that uploaded nothing before and the frames skipped after
    ending = header.rstrip()
    edge_ms = values[-4] if ending.endswith("dropped skipped") else \
        values[-2] if ending.endswith("dropped") else values[-1]
    return {"edge_ms": float(edge_ms),
            "device_ms_per_frame": (cpu1 - cpu0) / ((last - first) * slot_frames) * 1000,
            "untracked": float(untracked), "ate_m": float(values[ate])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", default="d48d6e2",
                        help="commit to compare with (default: the last on the own runtime)")
    parser.add_argument("--rounds", type=int, default=3, help="baseline/current pairs")
    parser.add_argument("--frames", type=int, default=600, help="frames played per run")
    parser.add_argument("--policy", default="adapt", help="the edge's policy")
    args = parser.parse_args()
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cores, python "
          f"{platform.python_version()}; {args.frames} frames of {SEQUENCE.name}, {args.policy}",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="twinslam-baseline-") as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(["git", "worktree", "add", "--detach", str(base), args.baseline],
                       cwd=REPO, check=True, capture_output=True)
        try:
            base_env = baseline_interfaces(args.baseline, base, Path(tmp) / "msgs")
            results: dict[str, list[dict[str, float]]] = {"baseline": [], "current": []}
            for i in range(args.rounds):
                for label, root in (("baseline", base.resolve()), ("current", REPO)):
                    res = run(root, args.frames, args.policy,
                              base_env if label == "baseline" else None)
                    results[label].append(res)
                    print(f"round {i + 1} {label:<8} edge {res['edge_ms']:6.1f} ms/slot, device "
                          f"{res['device_ms_per_frame']:6.1f} CPU ms/frame, ATE "
                          f"{res['ate_m']:.3f} m, untracked {res['untracked']:.0f}", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=REPO,
                           capture_output=True)
    for key in ("edge_ms", "device_ms_per_frame"):
        b = statistics.median(r[key] for r in results["baseline"])
        c = statistics.median(r[key] for r in results["current"])
        print(f"{key:<20} baseline {args.baseline} {b:7.1f}   current {c:7.1f}   "
              f"({(c / b - 1) * 100:+.1f} %)")


if __name__ == "__main__":
    main()
