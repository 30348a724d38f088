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
devices' copies). Where the files carry the device's search of the map it held (written
since the search columns came), two tables more: by the same bins, the share of the edge's
map points in view that the device searched for (the tracker searches ``max_candidates`` at
most) and the share of those searched that it found, the device's own edge map's against
other devices' copies'; and for the frames the edge counted lost against the others, the
points in view, searched, found and observed a frame (medians) — the edge map's own, other
devices' copies' and the device's own new points apart: a map that lacks the view, points
in view left unsearched, or points searched and not recognised. Where they carry the
points seen from afar too, a last table: of the edge's points in view and of those
searched, the share the frame saw from over 60° off the direction the map's keyframes saw
them from, for the frames the edge counted lost against the others (docs/results/
shared-map.md, "Copies seen from elsewhere").

    .venv/bin/python docs/figures/place_walks_frames.py NAME=FILE [NAME=FILE …]
"""

from __future__ import annotations

import argparse
import csv
import gzip
import itertools
import math
from collections import defaultdict
from pathlib import Path
from statistics import median
from typing import NamedTuple

from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS

#: the device's search columns of ``--frames-csv`` (bench.in_process.MapSearch), in order
SEARCH_COLUMNS = tuple(f"device_{what}_{who}" for what, whose in (
    ("in_view", ("own", "others", "device")), ("searched", ("own", "others", "device")),
    ("found", ("own", "others")), ("observed", ("own", "others"))) for who in whose)


class Frame(NamedTuple):
    """One served frame, as ``--frames-csv`` wrote it."""

    covered: bool
    uploaded: bool
    lost: bool              #: by the edge's rule
    held_served: bool       #: the device tracked it on MIN_INLIERS points of the map it held
    shared: int             #: map points it shared with the map the slot was planned on
    tracked: bool
    #: the device's search of the map it held (bench.in_process.MapSearch's fields: in view,
    #: searched, found, observed; by who made the points); None: a file written before the
    #: search columns came
    search: tuple[int, ...] | None = None


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
            search = (tuple(int(row[c]) for c in SEARCH_COLUMNS)
                      if SEARCH_COLUMNS[0] in row else None)
            out[row["device"]][int(row["slot"])].append(Frame(
                row["covered"] == "1", row["uploaded"] == "1", row["lost"] == "1",
                tracked and int(row["device_map_points"]) >= MIN_INLIERS, int(row["shared"]),
                tracked, search))
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


def searches(path: Path) -> dict[str, float] | None:
    """The device's searches of the maps it held, over the frames after each device's first
    slot: per bin of :data:`OWN_BINS`, the share of the edge's points in view searched for
    (``searched_i``) and of those searched the share found, own and others'
    (``found_own_i``, ``found_others_i``; NaN: none); for the frames the edge counted lost and
    the rest (``lost``, ``served``), their count and each :data:`SEARCH_COLUMNS` figure's
    median (``lost_device_in_view_own`` …). None: the file has no search columns."""
    served, owned = slots_of(path)
    fields = ("in_view_own", "in_view_others", "searched_own", "searched_others",
              "found_own", "found_others")
    sums = [dict.fromkeys(fields, 0) for _ in OWN_BINS]
    frames: dict[str, list[tuple[int, ...]]] = {"lost": [], "served": []}
    for device, slots in served.items():
        for slot in sorted(slots)[1:]:
            held = owned[device][slot]
            b = next(i for i, (lo, hi) in enumerate(OWN_BINS) if lo <= held <= hi)
            for f in slots[slot]:
                if f.search is None:
                    return None
                for name in fields:
                    sums[b][name] += f.search[SEARCH_COLUMNS.index(f"device_{name}")]
                frames["lost" if f.lost else "served"].append(f.search)
    out: dict[str, float] = {}
    for i, n in enumerate(sums):
        in_view = n["in_view_own"] + n["in_view_others"]
        searched = n["searched_own"] + n["searched_others"]
        out[f"searched_{i}"] = searched / in_view if in_view else math.nan
        for who in ("own", "others"):
            out[f"found_{who}_{i}"] = (n[f"found_{who}"] / n[f"searched_{who}"]
                                       if n[f"searched_{who}"] else math.nan)
    for kind, rows in frames.items():
        out[kind] = len(rows)
        for k, column in enumerate(SEARCH_COLUMNS):
            out[f"{kind}_{column}"] = median(r[k] for r in rows) if rows else math.nan
    return out


def _percent(share: float) -> str:
    return "–" if math.isnan(share) else f"{100 * share:.1f}"


def search_tables(runs: list[tuple[str, Path]]) -> list[str]:
    """The search tables' lines for ``runs`` (name, ``--frames-csv`` file); none where a
    file has no search columns."""
    named = [(name, searches(path)) for name, path in runs]
    if any(s is None for _, s in named):
        return []
    bins = [f"{lo}–{hi}" if hi < 10**6 else f"{lo} or more" for lo, hi in OWN_BINS]
    lines = ["| run | " + " | ".join(f"{b} own keyframes: the edge's points in view searched; "
                                     "found of those searched, own / others' (%)"
                                     for b in bins) + " |",
             "|---|" + "---|" * len(bins)]
    for name, s in named:
        assert s is not None
        cells = [f"{_percent(s[f'searched_{i}'])}; {_percent(s[f'found_own_{i}'])} / "
                 f"{_percent(s[f'found_others_{i}'])}" for i in range(len(OWN_BINS))]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "| run | frames | count | in view: own / others' / the device's new "
                  "(median) | searched: own / others' / the device's new (median) "
                  "| found: own / others' (median) | observed: own / others' (median) |",
              "|---|---|---|---|---|---|---|"]
    for name, s in named:
        assert s is not None
        for kind, label in (("lost", "lost by the edge"), ("served", "the others")):
            cells = [" / ".join(f"{s[f'{kind}_device_{what}_{who}']:.0f}" for who in whose)
                     for what, whose in (("in_view", ("own", "others", "device")),
                                         ("searched", ("own", "others", "device")),
                                         ("found", ("own", "others")),
                                         ("observed", ("own", "others")))]
            lines.append(f"| {name} | {label} | {s[kind]:.0f} | " + " | ".join(cells) + " |")
    return lines


#: the in-view and searched columns of the edge's points, and of them the ones seen from
#: afar (``bench.in_process.MapSearch``)
AFAR_COLUMNS = tuple(f"device_{what}_{who}" for what in ("in_view", "afar", "searched",
                                                         "searched_afar")
                     for who in ("own", "others"))


def afar(path: Path) -> dict[str, float] | None:
    """For the frames the edge counted lost and the rest (``lost``, ``served``): their count
    and, of the edge's points in view and of those searched, the share the frame saw from
    afar, own and others' (``lost_afar_own`` … ``served_searched_afar_others``). None: the
    file has no such columns."""
    sums = {kind: dict.fromkeys(AFAR_COLUMNS, 0) for kind in ("lost", "served")}
    count = dict.fromkeys(sums, 0)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            if AFAR_COLUMNS[2] not in row:
                return None
            kind = "lost" if row["lost"] == "1" else "served"
            count[kind] += 1
            for column in AFAR_COLUMNS:
                sums[kind][column] += int(row[column])
    out: dict[str, float] = {}
    for kind, n in sums.items():
        out[kind] = count[kind]
        for of, seen_afar in (("in_view", "afar"), ("searched", "searched_afar")):
            for who in ("own", "others"):
                total = n[f"device_{of}_{who}"]
                out[f"{kind}_{seen_afar}_{who}"] = (n[f"device_{seen_afar}_{who}"] / total
                                                    if total else math.nan)
    return out


def afar_table(runs: list[tuple[str, Path]]) -> list[str]:
    """The lines of the table of the edge's points seen from afar for ``runs`` (name,
    ``--frames-csv`` file); none where a file has no such columns."""
    named = [(name, afar(path)) for name, path in runs]
    if any(s is None for _, s in named):
        return []
    lines = ["| run | frames | count | of the edge's points in view, seen from over 60° off "
             "where the map saw them: own / others' (%) | of those searched: own / others' "
             "(%) |", "|---|---|---|---|---|"]
    for name, s in named:
        assert s is not None
        for kind, label in (("lost", "lost by the edge"), ("served", "the others")):
            cells = [" / ".join(_percent(s[f"{kind}_{what}_{who}"]) for who in ("own", "others"))
                     for what in ("afar", "searched_afar")]
            lines.append(f"| {name} | {label} | {s[kind]:.0f} | " + " | ".join(cells) + " |")
    return lines


def _share(lost: float, frames: float) -> str:
    return f"{100 * lost / frames:.1f}" if frames else "–"


def tables(runs: list[tuple[str, Path]]) -> list[str]:
    """The tables' lines for ``runs`` (name, ``--frames-csv`` file): three, and the two of
    :func:`search_tables` where every file has the search columns."""
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
    more = search_tables(runs)
    seen_afar = afar_table(runs)
    return lines + (["", *more] if more else []) + (["", *seen_afar] if seen_afar else [])


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
