"""The uplink a shared map saves (docs/results/shared-map.md, "Uplink saved"): per scenario
and device the keyframes uploaded alone, with the other device's map lent but every frame a
candidate, and with the frames the lent keyframes cover left out; the paired differences with
alone (Student's t over seeds, :func:`twinslam.reporting.paired_difference`) of uploads,
untracked frames and ATE; and a figure of the uploads, seed by seed.

Reads ``docs/figures/shared-map/uplink-{SCENARIO}-{alone,lent,covered}.csv`` written by
``bench.shared_map`` (the page has the commands) and writes
``docs/figures/shared-map/uplink-saved.png``; then the live runs' tables
(``uplink-live-{SCENARIO}-{covered,uncovered}-run{N}.csv``, each a ``twinslam launch``'s
``fleet_runs.csv``), run by run, and with three runs or more a device's paired difference.

    .venv/bin/python docs/figures/shared_uplink_table.py [SCENARIO ...]
"""

from __future__ import annotations

import csv
import itertools
import math
import sys
from pathlib import Path

import numpy as np

from twinslam.reporting import mean_ci95, paired_difference, pyplot

HERE = Path(__file__).resolve().parent / "shared-map"
#: the runs of a scenario: the device alone (no merge), lent keyframes without the coverage
#: rule, lent keyframes with it
CONDITIONS = ("alone", "lent", "covered")
SCENARIOS = {"mapped": "the second device walks the place the first walked (starts 500 frames "
                       "later)",
             "two-ends": "the two devices walk from the two ends, at once"}


def runs(scenario: str, condition: str) -> dict[int, dict[str, str]]:
    """seed → the run's CSV row."""
    path = HERE / f"uplink-{scenario}-{condition}.csv"
    with path.open(encoding="utf-8") as fh:
        return {int(r["seed"]): r for r in csv.DictReader(fh)}


#: columns that differ between two runs of one walk on one uplink only by the machine's load
TIMINGS = ("seed", "look_ms_median", "look_ms_max", "first_edge_ms", "second_edge_ms")


def distinct_seeds(by: dict[str, dict[int, dict[str, str]]]) -> list[int]:
    """The seeds every condition ran, less those whose runs repeat an earlier seed's in every
    condition (two seeds can draw one uplink; a repeated run is no second sample)."""
    seeds = sorted(set.intersection(*(set(r) for r in by.values())))
    seen: set[tuple[tuple[str, str], ...]] = set()
    kept = []
    for s in seeds:
        key = tuple((c, k + "=" + v) for c in sorted(by) for k, v in sorted(by[c][s].items())
                    if k not in TIMINGS)
        if key not in seen:
            seen.add(key)
            kept.append(s)
    return kept


def _mean(values: list[float], digits: int) -> str:
    mean, half = mean_ci95(values)
    return f"{mean:.{digits}f} ± {half:.{digits}f}" if math.isfinite(half) else \
        f"{mean:.{digits}f}"


def _diff(values: list[float], base: list[float], digits: int, scale: float = 1.0) -> str:
    d = paired_difference(np.array([[v * scale for v in values]]),
                          np.array([b * scale for b in base]))
    return f"{d.mean:+.{digits}f} [{d.low:+.{digits}f}, {d.high:+.{digits}f}]"


def table(scenario: str) -> list[str]:
    """The markdown rows of one scenario, a row per device."""
    by = {c: runs(scenario, c) for c in CONDITIONS}
    seeds = distinct_seeds(by)
    lines = []
    for device in ("first", "second"):
        def col(condition: str, column: str, scale: float = 1.0, device: str = device
                ) -> list[float]:
            return [float(by[condition][s][f"{device}_{column}"]) * scale for s in seeds]

        up = {c: col(c, "uploads") for c in CONDITIONS}
        saved = [100 * (1 - c / a) for c, a in zip(up["covered"], up["alone"], strict=True)]
        frames = [float(by["alone"][s]["frames"]) for s in seeds]
        cross = {c: [float(by[c][s]["cross_rms_m"]) for s in seeds] for c in ("lent", "covered")}
        failed = {c: [f - t for f, t in zip(frames, col(c, "tracked"), strict=True)]
                  for c in ("alone", "covered")}
        lines.append(
            f"| {scenario} | {device} | {len(seeds)} | {_mean(up['alone'], 1)} | "
            f"{_mean(up['lent'], 1)} | {_mean(up['covered'], 1)} | "
            f"{_diff(up['covered'], up['alone'], 1)} | {_mean(saved, 1)} % | "
            f"{_diff(failed['covered'], failed['alone'], 1)} | "
            f"{_diff(col('covered', 'ate_m'), col('alone', 'ate_m'), 2, 100)} | "
            f"{_diff(cross['covered'], cross['lent'], 2, 100)} | "
            f"{', '.join(str(s) for s in seeds)} |")
    return lines


def figure(scenarios: list[str]) -> Path:
    """Uploads per device and seed, alone / lent / covered, a panel a scenario."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5.5 * len(scenarios), 3.6),
                             squeeze=False)
    colours = {"alone": "#888888", "lent": "#7fa7d9", "covered": "#1f5fae"}
    for ax, scenario in zip(axes[0], scenarios, strict=True):
        by = {c: runs(scenario, c) for c in CONDITIONS}
        seeds = distinct_seeds(by)
        labels = [f"{d[0].upper()}{s}" for d in ("first", "second") for s in seeds]
        x = np.arange(len(labels))
        top = 0.0
        for i, c in enumerate(CONDITIONS):
            values = [float(by[c][s][f"{d}_uploads"]) for d in ("first", "second")
                      for s in seeds]
            ax.bar(x + (i - 1) * 0.27, values, 0.27, label=c, color=colours[c])
            top = max(top, *values)
        ax.set_ylim(0, top * 1.25)                 # room for the legend above the bars
        ax.set_xticks(x, labels)
        ax.set_xlabel("device (F first, S second) and seed")
        ax.set_ylabel("keyframes uploaded")
        ax.set_title(scenario)
        ax.legend(fontsize=8, ncol=3, loc="upper center")
    fig.tight_layout()
    out = HERE / "uplink-saved.png"
    fig.savefig(out, dpi=110)
    return out


def live_runs(scenario: str) -> list[dict[str, dict[str, dict[str, str]]]]:
    """The live runs of a scenario (``twinslam launch --devices 2 … --merge-maps``, each
    run's ``fleet_runs.csv`` as ``uplink-live-{SCENARIO}-{covered,uncovered}-run{N}.csv``,
    N = 1, 2, … while both exist): a run's setting → device → its row."""
    runs = []
    for run in itertools.count(1):
        paths = {setting: HERE / f"uplink-live-{scenario}-{setting}-run{run}.csv"
                 for setting in ("covered", "uncovered")}
        if not all(p.exists() for p in paths.values()):
            return runs
        tables = {}
        for setting, path in paths.items():
            with path.open(encoding="utf-8") as fh:
                tables[setting] = {r["device"]: r for r in csv.DictReader(fh)}
        runs.append(tables)
    return runs


def live_rows(scenario: str) -> list[str]:
    """A row a device and live run: frames uploaded with coverage against without, and
    then a device's paired summary over the runs."""
    rows, saved = [], {}
    for run, tables in enumerate(live_runs(scenario), start=1):
        for device in sorted(tables["covered"]):
            on, off = tables["covered"][device], tables["uncovered"][device]
            up_on, up_off = int(on["frames_uploaded"]), int(off["frames_uploaded"])
            saved.setdefault(device, []).append((up_on, up_off, float(on["ate_m"]),
                                                 float(off["ate_m"])))
            rows.append(
                f"| {scenario} | {run} (seed {on['seed']}) | {device} | {up_off} → {up_on} "
                f"({100 * (up_on - up_off) / up_off:+.0f} %) | {off['untracked_frames']} → "
                f"{on['untracked_frames']} | {off['frames_dropped']} → {on['frames_dropped']} | "
                f"{100 * float(off['ate_m']):.1f} → {100 * float(on['ate_m']):.1f} | "
                f"{100 * float(off['cross_device_rms_m']):.1f} → "
                f"{100 * float(on['cross_device_rms_m']):.1f} |")
    for device, pairs in sorted(saved.items()):
        if len(pairs) > 2:
            ups = [float(p[0]) for p in pairs]
            base = [float(p[1]) for p in pairs]
            share = [100 * (1 - a / b) for a, b in zip(ups, base, strict=True)]
            ate = _diff([p[2] for p in pairs], [p[3] for p in pairs], 2, 100)
            rows.append(f"| {scenario} | {len(pairs)} runs, paired | {device} | "
                        f"{_diff(ups, base, 1)} frames, {_mean(share, 1)} % saved | | | "
                        f"Δ {ate} | |")
    return rows


def main() -> None:
    scenarios = sys.argv[1:] or list(SCENARIOS)
    unknown = [s for s in scenarios if s not in SCENARIOS]
    if unknown:
        raise SystemExit(f"unknown scenario {', '.join(unknown)}: one of {', '.join(SCENARIOS)}")
    print("| scenario | device | runs | uploads alone | lent | lent + coverage | "
          "Δ uploads (coverage − alone) | share saved | Δ untracked frames | Δ ATE cm | "
          "Δ cross-device RMS cm (coverage − lent) | seeds |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for scenario in scenarios:
        print("\n".join(table(scenario)))
    print(f"wrote {figure(scenarios)}")
    print("\n| live scenario | run | device | frames uploaded, without → with coverage | "
          "untracked frames | camera frames dropped | ATE cm | cross-device RMS cm |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(row for scenario in scenarios for row in live_rows(scenario)))


if __name__ == "__main__":
    main()
