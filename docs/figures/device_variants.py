"""The tables of docs/results/update-loop.md, "A device that tracks with its own points when
lost": devices
and edges of several ``twinslam evaluate`` folders side by side, each against the first over
the same seeds:

    .venv/bin/python docs/figures/device_variants.py \\
        restores=docs/figures/own-map/constrained-restores \\
        own-map=docs/figures/own-map/constrained-own-map ...

Each ``LABEL=FOLDER`` holds the runs.csv and calibration_frames.csv (or .csv.gz) of one evaluate
run (one scenario, map source and policy); ``LABEL=FOLDER#SCENARIO`` takes that scenario's runs
of a folder that holds several. ``--user`` (first) gives the figures of runs made since the
plausibility gates instead (:data:`USER_FIGURES`: jumps of any tracked pose, the largest error,
jitter beside the truth's, the longest run of slots without an upload, the poses the gates
refused); ``--steady`` those of runs made since REP 105 (:data:`STEADY_FIGURES`: the revisit
error, the jitter in ``map`` and in ``odom``, the odom frame's largest step beyond the truth's,
the share of frames posed by PnP RANSAC, and each published pose anchored to its keyframe's final
pose: ATE and revisit error). ``--fixed-keyframes=LABEL[,LABEL]`` names variants whose
keyframes never moved once in the map (no loop closing, no bundle adjustment): their anchored
figures are their published ones, taken so where their runs.csv predates the column (a run of
theirs that closed a loop is refused). The first table gives each folder's figures a user
judges a device by, mean ± 95 % CI half-width over its runs (Student t, as evaluate's tables):
the share of played frames without a pose (a covered lens counted in), the share of the scored
next-slot frames the device failed (the covered lens counted apart, as calibrate does), the 95th
percentile and the longest loss, jumps, ATE, the edge's mean υ, lost share and υ over the
tracked frames (a lost frame scores 0; υ is undefined for a run whose map stayed empty, left out
of its mean), the uploads and the runs that uploaded nothing, the downlink, the device's CPU a
frame and the camera frames it dropped. The second says where each folder's failed frames come
from (calibrate's causes). The third gives each later folder minus the first, paired by seed:
mean [95 % CI] (twinslam.reporting.paired_difference, Student's t over seeds). A run whose
device dropped camera frames is refused: it measures the machine.
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np

from twinslam.live.calibration.report import (
    failure_causes,
    failure_causes_markdown,
    read_rows,
)
from twinslam.live.runs import anchored_as_published
from twinslam.reporting import mean_ci95, paired_difference

#: (column, heading, format); "scored_failed" is the share of the run's scored frames
#: (calibration_frames.csv) the device did not track
FIGURES = (("failed_share", "failed (played frames)", "{:.1%}"),
           ("scored_failed", "failed (scored, lens apart)", "{:.1%}"),
           ("loss_p95_s", "loss p95 (s)", "{:.2f}"), ("longest_loss_s", "longest loss (s)",
                                                      "{:.2f}"),
           ("jumps", "jumps", "{:.1f}"), ("ate_m", "ATE (m)", "{:.3f}"),
           ("mean_uncertainty", "mean υ", "{:.1f}"), ("lost_share", "lost share", "{:.3f}"),
           ("tracked_uncertainty", "υ tracked", "{:.1f}"),
           ("frames_uploaded", "uploads (frames)", "{:.1f}"),
           ("downlink_mb", "downlink (MB)", "{:.1f}"),
           ("device_cpu_ms", "device CPU (ms/frame)", "{:.1f}"),
           ("frames_dropped", "dropped (frames)", "{:.0f}"))
PAIRED = ("failed_share", "scored_failed", "ate_m", "frames_uploaded")
#: ``--user``: what a user of AR feels, as every live table reports it since the gates
USER_FIGURES = (("failed_share", "failed (played frames)", "{:.1%}"),
                ("longest_loss_s", "longest loss (s)", "{:.2f}"), ("jumps", "jumps", "{:.1f}"),
                ("max_error_m", "largest error (m)", "{:.3f}"), ("ate_m", "ATE (m)", "{:.3f}"),
                ("jitter_rms_mm", "jitter RMS (mm)", "{:.1f}"),
                ("jitter_p95_mm", "jitter p95 (mm)", "{:.1f}"),
                ("truth_jitter_rms_mm", "truth's jitter (mm)", "{:.1f}"),
                ("frames_uploaded", "uploads (frames)", "{:.1f}"),
                ("longest_no_upload_slots", "longest without upload (slots)", "{:.1f}"),
                ("poses_refused", "poses refused", "{:.1f}"),
                ("device_cpu_ms", "device CPU (ms/frame)", "{:.1f}"),
                ("frames_dropped", "dropped (frames)", "{:.0f}"))
USER_PAIRED = ("failed_share", "max_error_m", "ate_m", "jitter_rms_mm", "frames_uploaded")
#: ``--steady``: how steady and consistent the poses are, as runs report it since REP 105,
#: the revisit error and the PnP-RANSAC share
STEADY_FIGURES = (("failed_share", "failed (played frames)", "{:.1%}"),
                  ("max_error_m", "largest error (m)", "{:.3f}"), ("ate_m", "ATE (m)", "{:.3f}"),
                  ("anchored_ate_m", "ATE, anchored (m)", "{:.3f}"),
                  ("revisit_error_m", "revisit error (m)", "{:.3f}"),
                  ("anchored_revisit_error_m", "revisit error, anchored (m)", "{:.3f}"),
                  ("jitter_rms_mm", "jitter RMS (mm)", "{:.1f}"),
                  ("odom_jitter_rms_mm", "odom jitter RMS (mm)", "{:.1f}"),
                  ("odom_step_excess_mm", "odom step beyond the truth's (mm)", "{:.1f}"),
                  ("pnp_ransac_share", "PnP-RANSAC fallback", "{:.1%}"),
                  ("outlier_share", "outliers of the matches", "{:.1%}"),
                  ("duplicate_share", "map points twice (within 5 cm)", "{:.1%}"),
                  ("loops_closed", "loops closed", "{:.1f}"),
                  ("loops_refused", "loops refused", "{:.1f}"),
                  ("loop_closing_ms", "loop closing (ms)", "{:.0f}"),
                  ("frames_uploaded", "uploads (frames)", "{:.1f}"),
                  ("device_cpu_ms", "device CPU (ms/frame)", "{:.1f}"),
                  ("frames_dropped", "dropped (frames)", "{:.0f}"))
STEADY_PAIRED = ("max_error_m", "ate_m", "anchored_ate_m", "revisit_error_m",
                 "anchored_revisit_error_m", "jitter_rms_mm", "pnp_ransac_share")


def _runs(folder: Path, label: str, figures: tuple[tuple[str, str, str], ...] = FIGURES,
          scenario: str | None = None, fixed_keyframes: bool = False
          ) -> tuple[str, dict[int, dict[str, float]], list[dict[str, str]]]:
    """("scenario, map source, policy", seed → the run's figures, the scored frames labelled
    with ``label``) of one folder (of its runs of ``scenario`` only, when given);
    ``fixed_keyframes``: its anchored figures are its published ones where it lacks them."""
    with (folder / "runs.csv").open(encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if scenario in (None, r["scenario"])]
    if not rows:
        raise SystemExit(f"{folder}: no run{f' of scenario {scenario}' if scenario else ''}")
    kinds = {(r["scenario"], r["map_source"], r["policy"]) for r in rows}
    if len(kinds) != 1:
        raise SystemExit(f"{folder}: expected one scenario, map source and policy, got "
                         f"{sorted(kinds)}")
    dropped = [int(r["seed"]) for r in rows if int(r["frames_dropped"] or 0)]
    if dropped:
        raise SystemExit(f"{folder}: seeds {dropped} dropped camera frames; rerun with fewer "
                         "jobs")
    try:
        frames = [{**f, "folder": label}
                  for f in read_rows([folder], "calibration_frames.csv")
                  if scenario in (None, f["scenario"])]
    except FileNotFoundError as exc:
        raise SystemExit(str(exc)) from None
    if fixed_keyframes:
        try:
            rows = anchored_as_published(rows, folder)
        except ValueError as exc:
            raise SystemExit(str(exc)) from None
    runs = {}
    for r in rows:
        seed = int(r["seed"])
        runs[seed] = {k: float(r[k]) for k, _, _ in figures if k in r}
        tracked = [f["device_tracked"] == "1" for f in frames if int(f["seed"]) == seed]
        runs[seed]["scored_failed"] = (1.0 - float(np.mean(tracked))) if tracked else math.nan
    return ", ".join(sorted(kinds)[0]), runs, frames


def main(folders: list[tuple[str, Path]], user: bool = False, steady: bool = False,
         fixed_keyframes: frozenset[str] = frozenset()) -> None:
    """Print the tables of ``folders`` (label, folder, or folder#scenario); ``user``: the
    figures of :data:`USER_FIGURES` and :data:`USER_PAIRED`; ``steady``: those of
    :data:`STEADY_FIGURES` and :data:`STEADY_PAIRED`; ``fixed_keyframes``: the labels whose
    keyframes never moved (see the module's text)."""
    figures, paired = ((STEADY_FIGURES, STEADY_PAIRED) if steady else
                       (USER_FIGURES, USER_PAIRED) if user else (FIGURES, PAIRED))
    loaded = []
    for label, path in folders:
        folder, _, scenario = str(path).partition("#")
        loaded.append((label, *_runs(Path(folder), label, figures, scenario or None,
                                     label in fixed_keyframes)))
    # a figure no run measured (runs.csv written before its column) is left out of the table
    figures = tuple(f for f in figures
                    if any(f[0] in r for _, _, runs, _ in loaded for r in runs.values()))
    print("| variant | scenario, map source, policy | runs | runs without an upload | "
          + " | ".join(h for _, h, _ in figures) + " |")
    print("|---|---|---|---|" + "---|" * len(figures))
    for label, kind, runs, _ in loaded:
        cells = []
        for key, _, fmt in figures:
            mean, half = mean_ci95([r.get(key, math.nan) for r in runs.values()])  # NaN out
            cells.append("–" if math.isnan(mean) else f"{fmt.format(mean)} ± {fmt.format(half)}")
        idle = sum(r["frames_uploaded"] == 0 for r in runs.values())
        print(f"| {label} | {kind} | {len(runs)} | {idle} | " + " | ".join(cells) + " |")
    print()
    print(failure_causes_markdown(failure_causes([f for *_, frames in loaded for f in frames])))
    if len(loaded) < 2:
        return
    base_label, _, base, _ = loaded[0]
    formats = {k: f for k, _, f in figures}
    print()
    print(f"| variant − {base_label}, paired by seed | seeds | "
          + " | ".join(h for k, h, _ in figures if k in paired) + " |")
    paired = tuple(k for k in paired if k in formats)
    print("|---|---|" + "---|" * len(paired))
    for label, _, runs, _ in loaded[1:]:
        seeds = sorted(set(runs) & set(base))
        if seeds != sorted(runs) or seeds != sorted(base):
            raise SystemExit(f"{label} and {base_label} hold different seeds: no pairing")
        cells = []
        for key in paired:
            if not all(key in runs[s] and key in base[s] for s in seeds):
                cells.append("–")              # a variant's runs.csv predates the figure
                continue
            # a seed a variant could not measure (NaN) is left out of the pairing
            d = paired_difference(np.array([[runs[s][key] for s in seeds]]),
                                  [base[s][key] for s in seeds])
            fmt = formats[key]
            cells.append(f"{fmt.format(d.mean)} [{fmt.format(d.low)}, {fmt.format(d.high)}]")
        print(f"| {label} | {len(seeds)} | " + " | ".join(cells) + " |")


def _parse(items: list[str]) -> list[tuple[str, Path]]:
    out = []
    for item in items:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            raise SystemExit(f"{item!r}: expected LABEL=FOLDER[#SCENARIO]\n\n{__doc__}")
        out.append((label, Path(path)))
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    mode = args[0] if args and args[0] in ("--user", "--steady") else ""
    if mode:
        args = args[1:]
    fixed = frozenset(label for a in args if a.startswith("--fixed-keyframes=")
                      for label in a.partition("=")[2].split(",") if label)
    args = [a for a in args if not a.startswith("--fixed-keyframes=")]
    if not args:
        raise SystemExit(__doc__)
    main(_parse(args), user=mode == "--user", steady=mode == "--steady", fixed_keyframes=fixed)
