"""Where a process's thread spends its time, from py-spy's sampled stacks: the share of a
thread's samples inside each named function (inclusive: the function or anything it called),
one column a recording.

The recordings are py-spy's ``raw`` (collapsed stack) output, gzipped: ``py-spy record -p PID
-d 30 -r 67 -f raw --threads --nonblocking -o FILE`` on a live node process. Each line is one
stack, ``thread (tid): name;frame;frame;... count``, a frame ``function (file:line)``.

    python docs/figures/stack_shares.py LABEL=FILE.txt.gz [LABEL=FILE ...]
        [--thread MainThread] [--functions NAME,NAME,...]
"""

from __future__ import annotations

import argparse
import gzip
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

#: the functions the edge's table names, in its order (a frame's function, its class if any)
EDGE_FUNCTIONS = ("CheckedSubscription._on_data", "DeviceLink._on_summaries",
                  "DeviceLink._on_keyframe", "EdgeMapperCore.plan",
                  "LocalMapping.integrate", "DeviceLink.finish_due",
                  "read_frame_summaries", "deserialize_message", "RcutilsLogger.log",
                  "CallerId.__new__", "SiteLogger._emit")


def thread_shares(path: Path, thread: str) -> tuple[int, Counter[str]]:
    """The samples of the thread named ``thread`` in one recording, and for each function
    the samples whose stack passes through it (counted once a stack)."""
    samples, inside = 0, Counter[str]()
    with gzip.open(path, "rt", encoding="utf-8") as lines:
        for line in lines:
            stack, _, count = line.rstrip("\n").rpartition(" ")
            frames = stack.split(";")
            if not frames[0].endswith(f": {thread}"):
                continue
            n = int(count)
            samples += n
            for name in {frame.split(" (")[0] for frame in frames[1:]}:
                inside[name] += n
    return samples, inside


def table(recordings: Sequence[tuple[str, Path]], thread: str = "MainThread",
          functions: Sequence[str] = EDGE_FUNCTIONS) -> list[str]:
    """The markdown table: a row a function, a column a recording, its share of the
    thread's samples."""
    counted = [(label, *thread_shares(path, thread)) for label, path in recordings]
    lines = ["| function | " + " | ".join(label for label, _, _ in counted) + " |",
             "|---" * (len(counted) + 1) + "|",
             f"| {thread}'s samples | " + " | ".join(str(n) for _, n, _ in counted) + " |"]
    for name in functions:
        lines.append(f"| `{name}` | " + " | ".join(
            f"{100.0 * inside[name] / max(n, 1):.1f} %" for _, n, inside in counted) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", nargs="+", metavar="LABEL=FILE",
                        help="a column's label and its py-spy raw recording (.txt.gz)")
    parser.add_argument("--thread", default="MainThread", help="the thread's name")
    parser.add_argument("--functions", default=",".join(EDGE_FUNCTIONS),
                        help="the rows: functions as py-spy names them, comma-separated")
    args = parser.parse_args(argv)
    recordings = [(label, Path(path)) for label, _, path in
                  (item.partition("=") for item in args.recordings)]
    print("\n".join(table(recordings, args.thread, args.functions.split(","))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
