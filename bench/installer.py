"""What installing the requirements costs on a machine that has never installed them: a fresh
virtual environment each round, `tools/install_requirements.py` with uv and with pip
alternating round by round (both see the same machine load), each with an empty cache of its
own (uv's in a temporary folder, pip's switched off), so every wheel is fetched as on a clean
CI machine. Wall time and the CPU of the installer and everything it started.

    .venv/bin/python -m bench.installer [--rounds 2] [--installers uv,pip] [--csv FILE]

The machine's package sources are pip's configuration (find-links, mirrors, constraints), as
`make` uses them.
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.paths import REPO

INSTALLER = REPO / "tools" / "install_requirements.py"


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def install_once(installer: str, requirements: Path) -> dict[str, object]:
    """One install into a fresh venv with empty caches: seconds of wall and CPU, and how many
    distributions it left installed."""
    with tempfile.TemporaryDirectory(prefix="twinslam-bench-installer-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)   # not timed
        env = {**os.environ, "UV_CACHE_DIR": str(Path(tmp) / "uv-cache"),
               "PIP_NO_CACHE_DIR": "1"}
        cpu, started = _children_cpu(), time.perf_counter()
        done = subprocess.run([str(venv / "bin" / "python"), str(INSTALLER),
                               str(venv / "bin" / "python"), str(requirements),
                               "--installer", installer], env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - started, _children_cpu() - cpu
        if done.returncode:
            raise SystemExit(f"{installer} failed:\n{done.stdout}\n{done.stderr}")
        listed = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "list",
                                 "--format=freeze", "--disable-pip-version-check"],
                                capture_output=True, text=True, check=True).stdout
        return {"installer": installer, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
                "distributions": len(listed.splitlines())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2,
                        help="installs per installer, alternating (default %(default)s)")
    parser.add_argument("--installers", default="uv,pip",
                        help="comma-separated, in each round's order (default %(default)s)")
    parser.add_argument("--requirements", type=Path, default=REPO / "requirements.txt",
                        help="the requirements file (default: the project's)")
    parser.add_argument("--csv", type=Path, help="also write one row per install here")
    args = parser.parse_args()
    installers = [name.strip() for name in args.installers.split(",") if name.strip()]
    rows: list[dict[str, object]] = []
    for r in range(args.rounds):
        for installer in installers:
            row = {"round": r + 1, **install_once(installer, args.requirements)}
            rows.append(row)
            print(f"round {r + 1} {installer}: {row['wall_s']} s wall, {row['cpu_s']} s of CPU, "
                  f"{row['distributions']} distributions", flush=True)
    for installer in installers:
        walls = [float(str(row["wall_s"])) for row in rows if row["installer"] == installer]
        cpus = [float(str(row["cpu_s"])) for row in rows if row["installer"] == installer]
        print(f"{installer:<4} median {statistics.median(walls):.1f} s wall "
              f"({min(walls):.1f}-{max(walls):.1f}), {statistics.median(cpus):.1f} s of CPU, "
              f"{len(walls)} installs")
    if args.csv:
        with args.csv.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
