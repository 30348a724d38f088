"""The uplink a shared map saves (docs/results/shared-map.md, "Uplink saved"): per scenario
and device the keyframes uploaded alone, with the other device's map lent but every frame a
candidate, and with the frames the lent keyframes cover left out (by pose alone, and as the
edge does it); the paired differences with alone (Student's t over seeds,
:func:`twinslam.reporting.paired_difference`) of uploads, untracked frames and ATE; and a
figure of the uploads, seed by seed.

Reads ``uplink-{SCENARIO}-{alone,lent,pose-only,covered}.csv`` written by
``bench.shared_map`` (the page has the commands) from a folder — ``docs/figures/shared-map``
or one of its sets of runs, ``--folder`` (a condition without its file is left out) — and
writes ``uplink-saved.png`` there; then the live runs' tables
(``docs/figures/shared-map/uplink-live-{SCENARIO}-{uncovered,pose-only,covered}-run{N}.csv``
or those of ``--live-folder``, each a ``twinslam launch``'s ``fleet_runs.csv``), run by run,
and with three runs or more a device's paired difference.

    .venv/bin/python docs/figures/shared_uplink_table.py [SCENARIO ...] [--folder DIR]
        [--live-folder DIR]
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
from pathlib import Path

import numpy as np

from twinslam.reporting import mean_ci95, paired_difference, pyplot

HERE = Path(__file__).resolve().parent / "shared-map"
#: the runs of a scenario: the device alone (no merge), lent keyframes without the coverage
#: rule, with the rule by pose alone (every covered frame left out: the first version), and
#: with the rule as the edge has it (a covered frame the map cannot serve stays a candidate)
CONDITIONS = ("alone", "lent", "pose-only", "covered")
#: the live settings: coverage off (``covered_m: 0.0``), by pose alone, the edge's
LIVE_SETTINGS = ("uncovered", "pose-only", "covered")
SCENARIOS = {"mapped": "the second device walks the place the first walked (starts 500 frames "
                       "later)",
             "two-ends": "the two devices walk from the two ends, at once"}


def runs(folder: Path, scenario: str, condition: str) -> dict[int, dict[str, str]]:
    """seed → the run's CSV row."""
    path = folder / f"uplink-{scenario}-{condition}.csv"
    with path.open(encoding="utf-8") as fh:
        return {int(r["seed"]): r for r in csv.DictReader(fh)}


def conditions(folder: Path, scenario: str) -> list[str]:
    """The conditions ``folder`` has runs of for ``scenario``, in CONDITIONS' order; alone
    and lent are what every comparison stands on."""
    found = [c for c in CONDITIONS if (folder / f"uplink-{scenario}-{c}.csv").exists()]
    if "alone" not in found or "lent" not in found:
        raise SystemExit(f"{folder}: no uplink-{scenario}-alone.csv and -lent.csv to compare "
                         "with (bench.shared_map writes them)")
    return found


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


def table(folder: Path, scenario: str) -> list[str]:
    """The markdown rows of one scenario, a row per device and rule."""
    present = conditions(folder, scenario)
    by = {c: runs(folder, scenario, c) for c in present}
    seeds = distinct_seeds(by)
    lines = []
    for device in ("first", "second"):
        def col(condition: str, column: str, scale: float = 1.0, device: str = device
                ) -> list[float]:
            return [float(by[condition][s][f"{device}_{column}"]) * scale for s in seeds]

        up = {c: col(c, "uploads") for c in present}
        frames = [float(by["alone"][s]["frames"]) for s in seeds]
        cross = {c: [float(by[c][s]["cross_rms_m"]) for s in seeds] for c in present}
        for rule in (r for r in ("lent", "pose-only", "covered") if r in present):
            saved = [100 * (1 - c / a) for c, a in zip(up[rule], up["alone"], strict=True)]
            failed = {c: [f - t for f, t in zip(frames, col(c, "tracked"), strict=True)]
                      for c in ("alone", rule)}
            lines.append(
                f"| {scenario} | {device} | {rule} | {len(seeds)} | {_mean(up['alone'], 1)} | "
                f"{_mean(up['lent'], 1)} | {_mean(up[rule], 1)} | "
                f"{_diff(up[rule], up['alone'], 1)} | {_mean(saved, 1)} % | "
                f"{_diff(failed[rule], failed['alone'], 1)} | "
                f"{_diff(col(rule, 'ate_m'), col('alone', 'ate_m'), 2, 100)} | "
                f"{_diff(cross[rule], cross['lent'], 2, 100)} | "
                f"{_lost(by, rule, f'{device}_lost_share', seeds)} | "
                f"{_lost(by, rule, f'{device}_map_lost_share', seeds)} | "
                f"{', '.join(str(s) for s in seeds)} |")
    return lines


def _lost(by: dict[str, dict[int, dict[str, str]]], rule: str, column: str,
          seeds: list[int]) -> str:
    """A lost-frame share (``column``: the edge's rule, or the device's own count) with the
    rule against alone, in points, paired; "–" where the runs predate the column."""
    if any(not by[c][s].get(column) for c in (rule, "alone") for s in seeds):
        return "–"
    return _diff([float(by[rule][s][column]) for s in seeds],
                 [float(by["alone"][s][column]) for s in seeds], 1, 100)


def figure(folder: Path, scenarios: list[str]) -> Path:
    """Uploads per device and seed, alone / lent / pose-only / covered (those ``folder``
    has), a panel a scenario."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5.5 * len(scenarios), 3.6),
                             squeeze=False)
    colours = {"alone": "#888888", "lent": "#7fa7d9", "pose-only": "#e0a040",
               "covered": "#1f5fae"}
    for ax, scenario in zip(axes[0], scenarios, strict=True):
        present = conditions(folder, scenario)
        by = {c: runs(folder, scenario, c) for c in present}
        seeds = distinct_seeds(by)
        labels = [f"{d[0].upper()}{s}" for d in ("first", "second") for s in seeds]
        x = np.arange(len(labels))
        top = 0.0
        width = 0.8 / len(present)
        for i, c in enumerate(present):
            values = [float(by[c][s][f"{d}_uploads"]) for d in ("first", "second")
                      for s in seeds]
            ax.bar(x + (i - (len(present) - 1) / 2) * width, values, width, label=c,
                   color=colours[c])
            top = max(top, *values)
        ax.set_ylim(0, top * 1.25)                 # room for the legend above the bars
        ax.set_xticks(x, labels)
        ax.set_xlabel("device (F first, S second) and seed")
        ax.set_ylabel("keyframes uploaded")
        ax.set_title(scenario)
        ax.legend(fontsize=8, ncol=4, loc="upper center")
    fig.tight_layout()
    out = folder / "uplink-saved.png"
    fig.savefig(out, dpi=110)
    return out


def live_runs(scenario: str, folder: Path = HERE) -> list[dict[str, dict[str, dict[str, str]]]]:
    """The live runs of a scenario in ``folder`` (``twinslam launch --devices 2 …
    --merge-maps``, each run's ``fleet_runs.csv`` as
    ``uplink-live-{SCENARIO}-{SETTING}-run{N}.csv``, N = 1, 2, … while the run without
    coverage exists): a run's setting → device → its row."""
    runs = []
    for run in itertools.count(1):
        paths = {setting: folder / f"uplink-live-{scenario}-{setting}-run{run}.csv"
                 for setting in LIVE_SETTINGS}
        if not paths["uncovered"].exists():
            return runs
        tables = {}
        for setting, path in paths.items():
            if path.exists():
                with path.open(encoding="utf-8") as fh:
                    tables[setting] = {r["device"]: r for r in csv.DictReader(fh)}
        runs.append(tables)
    return runs


def live_rows(scenario: str, folder: Path = HERE) -> list[str]:
    """A row a device and live run (in ``folder``): frames uploaded with coverage against
    without, and then a device's paired summary over the runs."""
    rows, saved = [], {}
    for run, tables in enumerate(live_runs(scenario, folder), start=1):
        for rule, device in ((r, d) for r in LIVE_SETTINGS[1:] if r in tables
                             for d in sorted(tables[r])):
            on, off = tables[rule][device], tables["uncovered"][device]
            up_on, up_off = int(on["frames_uploaded"]), int(off["frames_uploaded"])
            saved.setdefault((rule, device), []).append(
                (up_on, up_off, float(on["ate_m"]), float(off["ate_m"]),
                 float(on["lost_share"]), float(off["lost_share"])))
            rows.append(
                f"| {scenario} | {rule} | {run} (seed {on['seed']}) | {device} | "
                f"{up_off} → {up_on} "
                f"({100 * (up_on - up_off) / up_off:+.0f} %) | {off['untracked_frames']} → "
                f"{on['untracked_frames']} | {off['frames_dropped']} → {on['frames_dropped']} | "
                f"{100 * float(off['ate_m']):.1f} → {100 * float(on['ate_m']):.1f} | "
                f"{100 * float(off['cross_device_rms_m']):.1f} → "
                f"{100 * float(on['cross_device_rms_m']):.1f} | "
                f"{100 * float(off['lost_share']):.1f} → {100 * float(on['lost_share']):.1f} |")
    for (rule, device), pairs in sorted(saved.items()):
        if len(pairs) > 2:
            ups = [float(p[0]) for p in pairs]
            base = [float(p[1]) for p in pairs]
            share = [100 * (1 - a / b) for a, b in zip(ups, base, strict=True)]
            ate = _diff([p[2] for p in pairs], [p[3] for p in pairs], 2, 100)
            lost = _diff([p[4] for p in pairs], [p[5] for p in pairs], 1, 100)
            rows.append(f"| {scenario} | {rule} | {len(pairs)} runs, paired | {device} | "
                        f"{_diff(ups, base, 1)} frames, {_mean(share, 1)} % saved | | | "
                        f"Δ {ate} | | Δ {lost} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                        help=f"of {', '.join(SCENARIOS)} (default: both)")
    parser.add_argument("--folder", type=Path, default=HERE,
                        help="the folder of in-process runs to read (default: %(default)s)")
    parser.add_argument("--live-folder", type=Path, default=HERE,
                        help="the folder of live runs to read (default: %(default)s)")
    args = parser.parse_args()
    scenarios = args.scenarios or list(SCENARIOS)
    unknown = [s for s in scenarios if s not in SCENARIOS]
    if unknown:
        parser.error(f"unknown scenario {', '.join(unknown)}: one of {', '.join(SCENARIOS)}")
    print("| scenario | device | rule | runs | uploads alone | lent | lent + rule | "
          "Δ uploads (rule − alone) | share saved | Δ untracked frames | Δ ATE cm | "
          "Δ cross-device RMS cm (rule − lent) | Δ the edge's lost share, points | "
          "Δ the device's own lost share, points | seeds |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for scenario in scenarios:
        print("\n".join(table(args.folder, scenario)))
    print(f"wrote {figure(args.folder, scenarios)}")
    print("\n| live scenario | rule | run | device | frames uploaded, without → with the rule | "
          "untracked frames | camera frames dropped | ATE cm | cross-device RMS cm | "
          "edge's lost share % |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(row for scenario in scenarios
                    for row in live_rows(scenario, args.live_folder)))


if __name__ == "__main__":
    main()
