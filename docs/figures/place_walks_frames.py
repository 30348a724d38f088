"""Where the edge's lost frames fall in a walk (docs/results/shared-map.md, "Where the cover
by points loses frames"): ``bench.place_walks --frames-csv`` files (gzipped or not), one a
run. A slot is **left to the cover** when the map covered every frame of it the device
tracked and the edge asked for none: nothing of the device's own view reaches the map, and
its next slot is tracked on what the other devices lent. Prints three markdown tables, a row a
run: the frames the edge served after each device's first slot, those it counted lost and,
of those, the ones the device tracked on ``MIN_INLIERS`` points of the map it held (the
edge's newer map had dropped the points it matched), the slots after one left to the cover
and the share of their frames lost against the share after every other slot; then the
frames lost a slot, and the median map points a tracked frame shares with the map, by how
many of the device's own keyframes the map it was planned on held (the rest were other
devices' copies).

    .venv/bin/python docs/figures/place_walks_frames.py NAME=FILE [NAME=FILE …]
"""

from __future__ import annotations

import argparse
import csv
import gzip
import itertools
from collections import defaultdict
from pathlib import Path
from statistics import median
from typing import NamedTuple

from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS


class Frame(NamedTuple):
    """One served frame, as ``--frames-csv`` wrote it."""

    covered: bool
    uploaded: bool
    lost: bool              #: by the edge's rule
    held_served: bool       #: the device tracked it on MIN_INLIERS points of the map it held
    shared: int             #: map points it shared with the map the slot was planned on
    tracked: bool


#: a slot's frames, capture order
Slot = list[Frame]
#: the bins of the device's own keyframes in its map: (lowest, highest)
OWN_BINS = ((0, 2), (3, 5), (6, 10), (11, 20), (21, 10**6))


def slots_of(path: Path) -> tuple[dict[str, dict[int, Slot]], dict[str, dict[int, int]]]:
    """device → slot → its frames, as ``--frames-csv`` wrote them (gzipped where the name
    ends in .gz); and device → slot → the device's own keyframes in the map it was planned
    on."""
    out: dict[str, dict[int, Slot]] = defaultdict(lambda: defaultdict(list))
    own: dict[str, dict[int, int]] = defaultdict(dict)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            tracked = row["tracked"] == "1"
            out[row["device"]][int(row["slot"])].append(Frame(
                row["covered"] == "1", row["uploaded"] == "1", row["lost"] == "1",
                tracked and int(row["device_map_points"]) >= MIN_INLIERS, int(row["shared"]),
                tracked))
            own[row["device"]][int(row["slot"])] = int(row["own_keyframes"])
    return out, own


def left_to_the_cover(frames: Slot) -> bool:
    """Every tracked frame covered (an untracked one is lost and never covered) and none
    asked for."""
    return any(f.covered for f in frames) and not any(f.uploaded for f in frames) and all(
        f.covered or f.lost for f in frames)


def summary(path: Path) -> dict[str, int]:
    """The run's figures: frames and lost frames after each device's first slot, slots left
    to the cover, and the lost shares of the slots after them and after the others; per bin
    of :data:`OWN_BINS`, its slots, the frames lost in them and the median map points a
    tracked frame of them shares with the map (``own_slots_i``, ``own_lost_i``,
    ``own_shared_i``; -1: no frame)."""
    frames = lost = left = held_served = 0
    after = {True: [0, 0], False: [0, 0]}          # left before? → [lost, frames]
    by_own = [[0, 0] for _ in OWN_BINS]             # [slots, lost]
    shared_by_own: list[list[int]] = [[] for _ in OWN_BINS]   # a tracked frame's shared
    served, owned = slots_of(path)
    for device, slots in served.items():
        order = sorted(slots)
        for before, slot in itertools.pairwise(order):
            this = slots[slot]
            n_lost = sum(f.lost for f in this)
            frames += len(this)
            lost += n_lost
            held_served += sum(f.lost and f.held_served for f in this)
            was_left = slot == before + 1 and left_to_the_cover(slots[before])
            left += was_left
            after[was_left][0] += n_lost
            after[was_left][1] += len(this)
            held = owned[device][slot]
            b = next(i for i, (lo, hi) in enumerate(OWN_BINS) if lo <= held <= hi)
            by_own[b][0] += 1
            by_own[b][1] += n_lost
            shared_by_own[b].extend(f.shared for f in this if f.tracked)
    out = {"frames": frames, "lost": lost, "left": left, "held_served": held_served,
           "lost_after_left": after[True][0], "frames_after_left": after[True][1],
           "lost_after_other": after[False][0], "frames_after_other": after[False][1]}
    for i, (slots_in, lost_in) in enumerate(by_own):
        out[f"own_slots_{i}"], out[f"own_lost_{i}"] = slots_in, lost_in
        out[f"own_shared_{i}"] = round(median(shared_by_own[i])) if shared_by_own[i] else -1
    return out


def _share(lost: float, frames: float) -> str:
    return f"{100 * lost / frames:.1f}" if frames else "–"


def tables(runs: list[tuple[str, Path]]) -> list[str]:
    """The two tables' lines for ``runs`` (name, ``--frames-csv`` file)."""
    named = [(name, summary(path)) for name, path in runs]
    lines = ["| run | frames served | lost by the edge (%) | of them, tracked on "
             f"{MIN_INLIERS} points of the map the device held (% of the frames) "
             "| slots after one left to the cover | lost in them (%) "
             "| lost after the other slots (%) |",
             "|---|---|---|---|---|---|---|"]
    for name, s in named:
        lines.append(f"| {name} | {s['frames']} | {_share(s['lost'], s['frames'])} "
                     f"| {_share(s['held_served'], s['frames'])} | {s['left']} "
                     f"| {_share(s['lost_after_left'], s['frames_after_left'])} "
                     f"({s['lost_after_left']} of {s['frames_after_left']}) "
                     f"| {_share(s['lost_after_other'], s['frames_after_other'])} |")
    bins = [f"{lo}–{hi}" if hi < 10**6 else f"{lo} or more" for lo, hi in OWN_BINS]
    lines += ["", "| run | " + " | ".join(f"{b} own keyframes: frames lost a slot (slots)"
                                           for b in bins) + " |",
              "|---|" + "---|" * len(bins)]
    for name, s in named:
        cells = [f"{s[f'own_lost_{i}'] / s[f'own_slots_{i}']:.2f} ({s[f'own_slots_{i}']})"
                 if s[f"own_slots_{i}"] else "–" for i in range(len(OWN_BINS))]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "| run | " + " | ".join(f"{b} own keyframes: a tracked frame's map points "
                                           "shared, median" for b in bins) + " |",
              "|---|" + "---|" * len(bins)]
    for name, s in named:
        cells = [str(s[f"own_shared_{i}"]) if s[f"own_shared_{i}"] >= 0 else "–"
                 for i in range(len(OWN_BINS))]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="NAME=FILE",
                        help="a run's name in the table and its --frames-csv file")
    args = parser.parse_args()
    runs = []
    for spec in args.runs:
        name, sep, file = spec.partition("=")
        if not sep:
            parser.error(f"{spec!r}: give NAME=FILE")
        runs.append((name, Path(file)))
    print("\n".join(tables(runs)))


if __name__ == "__main__":
    main()
