"""Whether the keyframe database's words tell places apart: frames of several places scored
against keyframes of all of them, under words learned from one place or from another dataset
(:mod:`twinslam.slam.back_end.keyframe_database`).

    python -m bench.keyframe_database [PLACE,PLACE,...] [--learn-from SEQUENCE[:KEYFRAMES]]
        [--words 256,512,1024] [--keyframes-a-row 1,4] [--every 20] [--csv FILE]

Every ``--every``-th frame of each place is filed as a keyframe of that place's map; the
frames half way between them are the queries, each scored against every keyframe filed. For
each place and vocabulary size it prints how many queries scored a keyframe of their own
place highest, the ratio of that score to the best keyframe of another place (median and
least: above 1, the own place wins), and how many queries had another place within the
database's candidate share of the best (where a look would also go to another map in turn);
then the time to score one query against every keyframe. ``--learn-from`` names the
sequence whose first keyframes (``KEYFRAMES`` of them; default 20) the words are learned
from: one of the places (its every ``--every``-th frame), or none of them (each frame: the
SUN3D apartment's 30 frames lie far apart). ``--keyframes-a-row`` compares how many of a
map's consecutive keyframes the database sums into one row (the rows are what a look's
ranking scores), in the places apart and in the ranking's time at scale.
"""

from __future__ import annotations

import argparse
import csv
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from bench.baseline import absolute_paths
from bench.paths import REPO, SEVEN_SCENES
from twinslam.cli.console import HelpFormatter
from twinslam.node_runtime.math_threads import one_math_thread
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.keyframe_database import (
    CANDIDATE_SHARE,
    KEYFRAMES_A_ROW,
    KeyFrameDatabase,
    WeightedWords,
)
from twinslam.slam.front_end.orb_extractor import OrbExtractor

PLACES = f"{SEVEN_SCENES},synthetic-corridor:1000,synthetic:1000"


def features(sequence: str, every: int, limit: int | None = None) -> dict[int, np.ndarray]:
    """The ORB descriptors of every ``every``/2-th frame of ``sequence`` by frame index (the
    keyframes and the queries half way between them), ``limit`` frames at most."""
    orb = OrbExtractor()
    out: dict[int, np.ndarray] = {}
    step = max(every // 2, 1)
    for frame in open_sequence(sequence):
        if frame.index % step == 0:
            out[frame.index] = orb.extract(frame.color).descriptors
            if limit is not None and len(out) >= limit:
                break
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("places", nargs="?", default=PLACES,
                        help="the places' sequences, separated by commas")
    parser.add_argument("--learn-from", default=f"{SEVEN_SCENES}:20",
                        help="SEQUENCE[:KEYFRAMES]: the words are learned from its first "
                        "KEYFRAMES keyframes (20 by default): every --every-th frame of one "
                        "of the places, or each frame of another sequence")
    parser.add_argument("--words", default="256,512,1024",
                        help="vocabulary sizes to compare, separated by commas")
    parser.add_argument("--keyframes-a-row", default=f"1,{KEYFRAMES_A_ROW}",
                        help="a map's consecutive keyframes summed into one row, the counts "
                        "to compare separated by commas")
    parser.add_argument("--every", type=int, default=20,
                        help="frames between two keyframes of a place (queries half way)")
    parser.add_argument("--keyframes", type=int, default=5000,
                        help="then a look's ranking timed over this many keyframes (the "
                        "places' filed again and again over --maps maps)")
    parser.add_argument("--maps", type=int, default=50, help="maps those keyframes are of")
    parser.add_argument("--csv", type=Path, help="append a row per place and size here")
    args = parser.parse_args()
    one_math_thread()                    # the math libraries' pools as in a node
    places = args.places.split(",")
    spec, _, count = args.learn_from.rpartition(":")
    if not spec or not count.isdigit():
        spec, count = args.learn_from, "20"
    print(f"# {platform.node()} {platform.processor() or platform.machine()}, "
          f"{time.strftime('%Y-%m-%d %H:%M')}", flush=True)
    frames = {}
    for place in places:
        started = time.perf_counter()
        frames[place] = features(place, args.every)
        print(f"# {place}: {len(frames[place])} frames' features in "
              f"{time.perf_counter() - started:.0f} s", flush=True)
    # one of the places, however its path is written (relative or absolute)
    learned = next((p for p in places if absolute_paths(p) == absolute_paths(spec)), None)
    if learned is not None:             # one of the places: its keyframes
        learning = [d for i, d in sorted(frames[learned].items()) if i % args.every == 0]
    else:                               # another dataset's frames, each one
        learning = list(features(spec, 2, int(count)).values())
    learning = learning[:int(count)]
    rows = []
    a_row = [int(n) for n in args.keyframes_a_row.split(",")]
    for words, per_row in ((int(w), n) for w in args.words.split(",") for n in a_row):
        database = KeyFrameDatabase(words=words, keyframes_a_row=per_row)
        database.words = WeightedWords.learn(learning, words)
        for place in places:
            for index, descriptors in frames[place].items():
                if index % args.every == 0:
                    database.add(place, index, descriptors)
        timing = []
        for place in places:
            ratios, near = [], 0
            for index, descriptors in frames[place].items():
                if index % args.every == 0:
                    continue
                started = time.perf_counter()
                scores = database.scores([descriptors], places)
                timing.append(time.perf_counter() - started)
                own = scores[place]
                other = max(s for p, s in scores.items() if p != place)
                ratios.append(own / other if other > 0 else float("inf"))
                near += other >= CANDIDATE_SHARE * max(own, other)
            won = sum(r > 1.0 for r in ratios)
            row = {"place": Path(place).name, "learned_from": Path(spec).name,
                   "learned_keyframes": len(learning), "words": words,
                   "keyframes_a_row": per_row, "queries": len(ratios), "own_first": won,
                   "ratio_median": round(statistics.median(ratios), 3),
                   "ratio_least": round(min(ratios), 3), "another_candidate": near}
            rows.append(row)
            print(f"{words:5d} words {per_row:2d} a row  {row['place']:<22} own place "
                  f"first {won}/{len(ratios)}"
                  f"  own/other median {row['ratio_median']:.2f} least "
                  f"{row['ratio_least']:.2f}  another within {CANDIDATE_SHARE:.0%}: {near}",
                  flush=True)
        filed = sum(database.keyframes(p) for p in places)
        print(f"{words:5d} words {per_row:2d} a row  scoring a query against {filed} "
              f"keyframes ({database.rows} rows): median "
              f"{statistics.median(timing) * 1e3:.2f} ms (words assigned included)", flush=True)
    if args.keyframes:
        for per_row in a_row:
            _time_at_scale(places, frames, learning, args, per_row)
    if args.csv:
        new = not args.csv.exists()
        with args.csv.open("a", newline="") as out:
            writer = csv.DictWriter(out, fieldnames=list(rows[0]))
            if new:
                writer.writeheader()
            writer.writerows(rows)
        shown = args.csv.relative_to(REPO) if args.csv.is_relative_to(REPO) else args.csv
        print(f"# rows appended to {shown}")


def _time_at_scale(places: list[str], frames: dict[str, dict[int, np.ndarray]],
                   learning: list[np.ndarray], args: argparse.Namespace, per_row: int) -> None:
    """A look's ranking (three keyframes scored against every map) where ``--keyframes``
    keyframes of ``--maps`` maps are filed ``per_row`` a row, under the database's default
    words; and what filing costs a keyframe (its words assigned: the worker's time for every
    upload)."""
    database = KeyFrameDatabase(keyframes_a_row=per_row)
    database.words = WeightedWords.learn(learning)
    filed = [d for place in places for i, d in frames[place].items() if i % args.every == 0]
    maps = [f"ar{m + 1}" for m in range(args.maps)]
    for n in range(args.keyframes):
        database.add(maps[n % len(maps)], n, filed[n % len(filed)])
    started = time.perf_counter()
    database.scores([], [])
    filing = (time.perf_counter() - started) / args.keyframes
    timing = []
    newest = (args.keyframes // len(maps) - 3) * len(maps)     # a map's third newest round
    for look in range(20):          # a look ranks the three keyframes its device filed last
        started = time.perf_counter()
        database.candidates_of(maps[look % len(maps)],
                               [newest + look % len(maps) + k * len(maps) for k in range(3)],
                               maps)
        timing.append(time.perf_counter() - started)
    print(f" {database.word_count} words {per_row:2d} a row  {args.keyframes} keyframes "
          f"({database.rows} rows) over {args.maps} maps: "
          f"filing {filing * 1e3:.2f} ms a keyframe; a look's ranking (3 filed keyframes) "
          f"median {statistics.median(timing) * 1e3:.2f} ms", flush=True)


if __name__ == "__main__":
    main()
