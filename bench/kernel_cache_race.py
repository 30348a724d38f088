"""Processes compiling overloads of one cached numba kernel at once: how often the shared cache
loses an overload or hands one overload another's machine code, with the save under
``twinslam.kernel_cache``'s lock and with numba's own save.

    .venv/bin/python -m bench.kernel_cache_race [--rounds 5] [--no-lock]

Each round: a fresh folder with one ``cache=True`` kernel, eight processes that each compile
one overload (eight argument types) starting at the same instant, then a fresh process that
loads every overload and checks its answer. A round is bad when the index names fewer than
eight files or an overload answers wrongly (it ran another overload's code).
"""

from __future__ import annotations

import argparse
import ast
import os
import pickle
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from bench.paths import REPO

#: one value of each argument type, and what 2x + 1 gives for it
VALUES = ("np.int64(3)", "np.float64(3.5)", "np.float32(1.5)", "np.int32(2)", "np.int16(4)",
          "np.uint8(5)", "np.uint16(6)", "np.int8(-3)")
EXPECTED = [7.0, 8.0, 4.0, 5.0, 9.0, 11.0, 13.0, -5.0]
_COMPILE = """
import sys, time
import numpy as np
import kernel
value = eval(sys.argv[1])
while time.time() < float(sys.argv[2]):
    pass
kernel.twice_plus_one(value)
"""
_CHECK = f"""
import numpy as np
import kernel
print([float(kernel.twice_plus_one(v)) for v in ({", ".join(VALUES)})])
"""


def kernel_env(folder: Path) -> dict[str, str]:
    """The environment of a process that imports ``kernel`` from ``folder`` (and twinslam)."""
    return dict(os.environ, PYTHONPATH=f"{folder}{os.pathsep}{REPO}")


def read_index(folder: Path) -> tuple[Path, dict[object, str]]:
    """The index file of ``kernel.twice_plus_one``'s cache in ``folder`` and what it holds:
    each overload's key → the data file its machine code is in."""
    (path,) = (folder / "__pycache__").glob("kernel.twice_plus_one-*.nbi")
    with path.open("rb") as fh:
        pickle.load(fh)                                  # numba's version
        _, overloads = pickle.loads(fh.read())
    return path, overloads


def _round(lock: bool) -> tuple[int, list[float]]:
    """One round: the overloads the index names and what a fresh process computes."""
    kernel = textwrap.dedent(f"""
        from {'twinslam.kernel_cache' if lock else 'numba'} import njit


        @njit(cache=True)
        def twice_plus_one(x):
            return x * 2 + 1
    """)
    with tempfile.TemporaryDirectory(prefix="twinslam-kernel-cache-") as tmp:
        folder = Path(tmp)
        (folder / "kernel.py").write_text(kernel, encoding="utf-8")
        env = kernel_env(folder)
        start = time.time() + 4.0                  # every process imported numba by then
        procs = [subprocess.Popen([sys.executable, "-c", _COMPILE, value, str(start)],
                                  cwd=folder, env=env) for value in VALUES]
        for proc in procs:
            proc.wait(timeout=300)
        _, overloads = read_index(folder)
        done = subprocess.run([sys.executable, "-c", _CHECK], cwd=folder, env=env,
                              capture_output=True, text=True, timeout=300, check=True)
        return len(set(overloads.values())), ast.literal_eval(done.stdout.strip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5, help="rounds (default %(default)s)")
    parser.add_argument("--no-lock", action="store_true",
                        help="numba's own save, without twinslam.kernel_cache's lock")
    args = parser.parse_args()
    lock = not args.no_lock
    bad = 0
    for r in range(args.rounds):
        files, answers = _round(lock)
        wrong = [f"{v} → {a:g}" for v, a, e in zip(VALUES, answers, EXPECTED, strict=True)
                 if a != e]
        bad += files < len(VALUES) or bool(wrong)
        print(f"round {r + 1}: {files} of {len(VALUES)} overloads in the index"
              + (f"; wrong answers: {', '.join(wrong)}" if wrong else ""), flush=True)
    print(f"{'with the lock' if lock else 'numba alone'}: {bad} of {args.rounds} rounds bad")


if __name__ == "__main__":
    main()
