"""``twinslam calibrate``: what live runs say the rule of a lost frame must be.

Reads the ``calibration_frames.csv`` and ``calibration.csv`` that ``twinslam evaluate`` wrote in
one or more folders (:func:`read_rows`, once) and measures, per device map source:

* the **lag**: how many first frames of a slot the device tracked with an older map version
  than the slot's newest (the update of the previous slot still on its way);
* the **threshold** k of "lost: fewer than k shared map points", fitted on every frame
  against the map the device really held (so the lag does not blur it): the k of the best
  balanced accuracy (:func:`~twinslam.live.calibration.prediction.fit_min_shared`) and the k at
  which the predicted lost share reaches the device's failure share
  (:func:`~twinslam.live.calibration.prediction.level_min_shared`);
* how well the rule the runs were scored with predicts each run: Pearson's r over runs of the
  predicted lost share and the device's failure share, over all runs and per scenario (the
  calibration table: :func:`agreement_by_scenario`);
* where the device's failed frames come from (:func:`failure_causes`): new ground no upload
  had reached, places integrated keyframes covered but the device's map left out, or places
  its map covered where tracking still failed.

It draws ``rule-calibration.png``: per run, predicted lost share against device failure share (one
colour per map source); and the device's failure rate against the shared map points, the
fitted thresholds marked.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from twinslam.live.calibration.prediction import (
    FAILURE_CAUSES,
    LEFT_OUT,
    MAP_COVERED,
    NEW_GROUND,
    CalibrationFrame,
    FramePrediction,
    balanced_accuracy,
    fit_min_shared,
    level_min_shared,
)
from twinslam.reporting import pearson_r, pyplot

#: what names a run: two folders may hold runs of the same scenario, policy and seed
RUN_KEY = ("folder", "scenario", "map_source", "policy", "seed", "spec")


@dataclass(frozen=True)
class SourceCalibration:
    """What one map source's runs measured."""

    map_source: str
    runs: int
    frames: int
    failure_share: float
    lag_median: float               #: frames a slot tracked with the previous map version
    lag_mean: float
    k_balanced: int                 #: the best-separating threshold...
    balanced_accuracy: float        #: ...and its balanced accuracy
    k_level: int                    #: the threshold whose predicted share meets the failures
    level_balanced_accuracy: float
    min_shared: int                 #: the threshold the runs were scored with
    r_over_runs: float              #: Pearson r, predicted lost share vs failure share


def _read(path: Path) -> list[dict[str, str]]:
    """The CSV's rows, each with the folder it came from; the CSV as ``twinslam evaluate``
    wrote it or gzipped beside where it was (``NAME.csv.gz``, as the results commit it)."""
    packed = path.with_name(path.name + ".gz")
    if path.is_file():
        text = path.read_text(encoding="utf-8")
    elif packed.is_file():
        text = gzip.decompress(packed.read_bytes()).decode("utf-8")
    else:
        raise FileNotFoundError(f"{path} does not exist (written by `twinslam evaluate`)")
    # rows zipped with the header, not csv.DictReader's: a 280-run sweep's frames are 1.5
    # million rows, and building each dict field by field took most of a table's time
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        return []
    keys, folder = (*header, "folder"), str(path.parent)
    rows: list[dict[str, str]] = []
    for row in reader:
        if len(row) == len(header):
            rows.append(dict(zip(keys, (*row, folder), strict=True)))
        elif row:                                    # blank lines are skipped, as csv's are
            raise ValueError(f"{path}, line {reader.line_num}: {len(row)} fields where the "
                             f"header has {len(header)}")
    return rows


def read_rows(folders: list[Path], name: str) -> list[dict[str, str]]:
    """The rows of ``name`` (``calibration.csv`` or ``calibration_frames.csv``, or either
    gzipped) in every folder, each with its folder: read once and handed to every measure and
    the figure (the frames of a 280-run sweep are 31 MB)."""
    return [r for folder in folders for r in _read(folder / name)]


def _run(row: dict[str, str]) -> tuple[str, ...]:
    return tuple(row.get(k, "") for k in RUN_KEY)


def _frames(rows: Iterable[dict[str, str]]) -> list[CalibrationFrame]:
    """The frames as predicted against the map the device held when it tracked them."""
    return [CalibrationFrame(FramePrediction(int(r["shared_points_tracked_map"]),
                                             float(r["covisibility_tracked_map"]),
                                             float(r["uncertainty_tracked_map"])),
                             r["device_tracked"] == "1", int(r["inliers"]),
                             float(r["translation_error_m"]))
            for r in rows]


def lag_per_slot(rows: Iterable[dict[str, str]]) -> list[int]:
    """Per run and slot: its frames tracked with an older map version than the slot's newest."""
    slots: dict[tuple[Any, ...], list[int]] = {}
    for r in rows:
        slots.setdefault((*_run(r), r["slot"]), []).append(int(r["map_version"]))
    return [sum(v < max(versions) for v in versions) for versions in slots.values()]


def calibrate_runs(runs: list[dict[str, str]], frames: list[dict[str, str]]
                   ) -> list[SourceCalibration]:
    """Every map source's measurements over the rows of calibration.csv (``runs``) and
    calibration_frames.csv (``frames``)."""
    out = []
    for source in dict.fromkeys(r["map_source"] for r in runs):
        mine = [r for r in frames if r["map_source"] == source]
        scored = [r for r in runs if r["map_source"] == source and int(r["frames"])]
        cal = _frames(mine)
        if not cal:
            continue
        failures = sum(not f.device_tracked for f in cal) / len(cal)
        lags = lag_per_slot(mine)
        try:
            k_bal, acc = fit_min_shared(cal)
            k_level = level_min_shared(cal)
        except ValueError:            # nothing failed (or nothing tracked): nothing to fit
            k_bal, acc, k_level = 0, math.nan, 0
        pred = np.array([float(r["predicted_lost_share"]) for r in scored])
        fail = np.array([float(r["device_failure_share"]) for r in scored])
        r_runs = pearson_r(pred, fail)
        out.append(SourceCalibration(
            source, len(scored), len(cal), failures, float(np.median(lags)),
            float(np.mean(lags)), k_bal, acc, k_level,
            balanced_accuracy(cal, k_level) if k_level else math.nan,
            int(scored[0]["min_shared"]) if scored else 0, r_runs))
    return out


@dataclass(frozen=True)
class ScenarioAgreement:
    """How well the rule predicted the runs of one map source and scenario: the calibration
    table of docs/results/paper-device.md. Shares and measures are means over runs; ``r`` is
    over runs."""

    map_source: str
    scenario: str
    runs: int
    predicted_lost_share: float
    device_failure_share: float
    mean_abs_error: float           #: of the predicted share per run, in share points
    r_over_runs: float              #: NaN below 3 runs or without spread
    precision: float                #: P(device failed | predicted lost), mean over runs
    recall: float                   #: P(predicted lost | device failed), mean over runs
    spearman_u_error: float         #: ρ(u, translation error), mean over runs
    spearman_u_inliers: float       #: ρ(u, inlier count), mean over runs


def _nanmean(values: Iterable[str]) -> float:
    v = np.array([float(x) for x in values], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def agreement_by_scenario(rows: list[dict[str, str]]) -> list[ScenarioAgreement]:
    """Per map source and scenario (in the order the runs came; "all" last per map source):
    the predicted lost share beside the device's failure share, and the per-run measures
    the rows of calibration.csv hold. r over one scenario's runs says whether the rule
    follows the run-to-run variation, not only the level."""
    runs = [r for r in rows if int(r["frames"])]
    out = []
    for source in dict.fromkeys(r["map_source"] for r in runs):
        mine = [r for r in runs if r["map_source"] == source]
        groups = {s: [r for r in mine if r["scenario"] == s]
                  for s in dict.fromkeys(r["scenario"] for r in mine)}
        if len(groups) > 1:
            groups["all"] = mine
        for scenario, rows in groups.items():
            pred = np.array([float(r["predicted_lost_share"]) for r in rows])
            fail = np.array([float(r["device_failure_share"]) for r in rows])
            out.append(ScenarioAgreement(
                source, scenario, len(rows), float(pred.mean()), float(fail.mean()),
                float(np.abs(pred - fail).mean()), pearson_r(pred, fail),
                _nanmean(r["precision"] for r in rows), _nanmean(r["recall"] for r in rows),
                _nanmean(r["spearman_u_error"] for r in rows),
                _nanmean(r["spearman_u_inliers"] for r in rows)))
    return out


def agreement_markdown(rows: list[ScenarioAgreement]) -> str:
    """The table :func:`agreement_by_scenario` measures, as docs/results/paper-device.md shows
    it."""
    lines = ["| map source | scenario | runs | predicted lost | device failed | mean abs. "
             "error | r over runs | precision | recall | ρ(u, error) | ρ(u, inliers) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {a.map_source} | {a.scenario} | {a.runs} | {a.predicted_lost_share:.1%} | "
              f"{a.device_failure_share:.1%} | {100 * a.mean_abs_error:.1f} pts | "
              f"{a.r_over_runs:.2f} | "
              f"{a.precision:.2f} | {a.recall:.2f} | {a.spearman_u_error:.2f} | "
              f"{a.spearman_u_inliers:.2f} |" for a in rows]
    return "\n".join(lines)


def plot_calibration(runs: list[dict[str, str]], frames: list[dict[str, str]],
                     results: list[SourceCalibration], path: Path) -> None:
    """The figure of the module docstring, from the rows :func:`calibrate_runs` measured."""
    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5.2))
    for res in results:
        mine = [r for r in runs if r["map_source"] == res.map_source and int(r["frames"])]
        left.scatter([float(r["predicted_lost_share"]) for r in mine],
                     [float(r["device_failure_share"]) for r in mine], s=14, alpha=0.7,
                     label=f"{res.map_source}: {res.runs} runs scored with k = "
                     f"{res.min_shared}, r = {res.r_over_runs:.2f}")
        shared = np.array([int(r["shared_points_tracked_map"]) for r in frames
                           if r["map_source"] == res.map_source])
        failed = np.array([r["device_tracked"] == "0" for r in frames
                           if r["map_source"] == res.map_source])
        edges = np.unique(np.round(np.geomspace(1, max(2, shared.max() + 1), 25)))
        edges = np.concatenate([[0], edges])
        idx = np.digitize(shared, edges) - 1
        centres, rates = [], []
        for b in range(len(edges) - 1):
            inside = idx == b
            if inside.sum() >= 20:
                centres.append(max(0.5, float(np.median(shared[inside]))))
                rates.append(float(failed[inside].mean()))
        right.plot(centres, rates, marker="o", label=f"{res.map_source} ({res.frames} frames)")
        if res.k_balanced:
            right.axvline(res.k_balanced, ls=":", color="grey")
    rule = results[0].min_shared if results else 0
    if rule:
        right.axvline(rule, ls="--", color="black", label=f"the rule: k = {rule}")
    left.plot([0, 1], [0, 1], color="black", lw=0.8)
    left.set_xlabel("predicted lost share (the simulator's rule, per run)")
    left.set_ylabel("device failure share (per run)")
    left.set_title("next-slot frames the simulator calls lost vs the device lost")
    left.legend()
    left.grid(alpha=0.3)
    right.set_xscale("symlog", linthresh=1)
    right.set_xlim(left=0)
    right.set_xlabel("map points the frame shares with the map the device held (simulator)")
    right.set_ylabel("device failure rate")
    right.set_title("the device fails where few points are shared")
    right.legend()
    right.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report_lines(results: list[SourceCalibration]) -> list[str]:
    lines = []
    for r in results:
        lines.append(
            f"{r.map_source}: {r.runs} runs, {r.frames} next-slot frames, device failed "
            f"{r.failure_share:.1%}; lag: median {r.lag_median:.0f} frames a slot (mean "
            f"{r.lag_mean:.1f}) on the previous map; threshold: best separation k = "
            f"{r.k_balanced} (balanced accuracy {r.balanced_accuracy:.3f}), level with the "
            f"failures k = {r.k_level} (balanced accuracy {r.level_balanced_accuracy:.3f}); "
            f"scored with k = {r.min_shared}: predicted vs failed share over runs r = "
            f"{r.r_over_runs:.2f}")
    return lines


@dataclass(frozen=True)
class FailureCauses:
    """Where one group's failed frames came from
    (:func:`~twinslam.live.calibration.prediction.failure_cause`): counts over its runs' scored
    next-slot frames."""

    folder: str
    scenario: str
    map_source: str
    policy: str
    runs: int
    frames: int
    failed: int
    new_ground: int             #: no keyframe the edge had integrated covered the place
    left_out: int               #: integrated keyframes covered it, the device's map did not
    map_covered: int            #: the device's map covered it and tracking still failed


def failure_causes(frames: list[dict[str, str]]) -> list[FailureCauses]:
    """Per folder, scenario, map source and policy (in the order the rows came), the causes of
    the device's failed frames from the ``failure_cause`` column of calibration_frames.csv;
    a ValueError where the frames were written before that column existed."""
    if frames and "failure_cause" not in frames[0]:
        raise ValueError("calibration_frames.csv has no failure_cause column: written by an "
                         "older twinslam evaluate")
    groups: dict[tuple[str, ...], list[dict[str, str]]] = {}
    for r in frames:
        groups.setdefault((r["folder"], r["scenario"], r["map_source"], r["policy"]),
                          []).append(r)
    out = []
    for (folder, scenario, source, policy), rows in groups.items():
        causes = [r["failure_cause"] for r in rows if r["device_tracked"] != "1"]
        if any(c not in FAILURE_CAUSES for c in causes):
            raise ValueError(f"{folder}: a failed frame without a known failure_cause "
                             f"(resumed into a folder of an older twinslam evaluate?)")
        out.append(FailureCauses(folder, scenario, source, policy,
                                 len({r["seed"] for r in rows}), len(rows), len(causes),
                                 causes.count(NEW_GROUND), causes.count(LEFT_OUT),
                                 causes.count(MAP_COVERED)))
    return out


def failure_causes_markdown(rows: list[FailureCauses]) -> str:
    """The table of :func:`failure_causes`: each cause's share of the scored frames (they add
    up to the failed share), its count in brackets."""
    def cell(n: int, of: int) -> str:
        return f"{n / of:.1%} ({n})" if of else "–"

    lines = ["| folder | scenario | map source | policy | runs | frames | failed | "
             f"{' | '.join(FAILURE_CAUSES)} |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {Path(c.folder).name} | {c.scenario} | {c.map_source} | {c.policy} | "
              f"{c.runs} | {c.frames} | {cell(c.failed, c.frames)} | "
              f"{cell(c.new_ground, c.frames)} | {cell(c.left_out, c.frames)} | "
              f"{cell(c.map_covered, c.frames)} |" for c in rows]
    return "\n".join(lines)
