"""The tables and the figure of a live evaluation: per scenario x map source x policy the mean
± 95 % CI over seeds, the paired difference of each policy against the best rule policy seed by
seed, the predicted-vs-failed agreement, and the side-by-side lines ``make run`` prints."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from twinslam.live.runs import RunResult
from twinslam.reporting import mean_ci95, paired_difference, pearson_r, pyplot, write_csv

#: the figures summarised per scenario × policy: (field, column title, unit); the fields are
#: RunReport's, and the calibration's two shares
METRICS = (("ate_m", "ATE", "m"), ("rpe_m", "RPE 1 s", "m"),
           ("tracking_failures", "failures", ""), ("relocalisations", "relocalisations", ""),
           ("recover_s", "recover", "s"), ("untracked_frames", "untracked", "frames"),
           # the device's failures among the scored next-slot frames, beside what the
           # simulator's rule predicted for them (calibration.csv)
           ("device_failure_share", "device failed", ""),
           ("predicted_lost_share", "predicted lost", ""),
           # MapStats' υ three ways: a lost next-slot frame scoring 0, the lost share, and
           # the tracked frames only (docs/architecture.md §2)
           ("mean_uncertainty", "mean υ", ""), ("lost_share", "lost share", ""),
           ("tracked_uncertainty", "υ tracked", ""),
           ("frames_uploaded", "uploads", "frames"), ("edge_ms_median", "edge", "ms/slot"),
           # what a user of the device lives through: the share of frames without a pose,
           # how long a loss lasts nearly at worst and at worst, poses that jumped, and the
           # camera frames the device dropped (a run that dropped any measured the machine)
           ("failed_share", "failed", ""), ("loss_p95_s", "loss p95", "s"),
           ("longest_loss_s", "longest loss", "s"), ("jumps", "jumps", ""),
           # how far off and how shaky the published pose was: the largest aligned error, the
           # second difference of positions (RMS, median, p95, frames over 20 mm) beside the
           # ground truth's own, and the poses and uploads the plausibility gates refused
           ("max_error_m", "largest error", "m"), ("jitter_rms_mm", "jitter RMS", "mm"),
           ("jitter_median_mm", "jitter median", "mm"), ("jitter_p95_mm", "jitter p95", "mm"),
           ("jitter_over_20mm", "jitter > 20 mm", "frames"),
           ("truth_jitter_rms_mm", "truth's jitter", "mm"),
           ("poses_refused", "poses refused", "frames"),
           ("keyframes_refused", "keyframes refused", ""),
           ("longest_no_upload_slots", "longest without upload", "slots"),
           ("downlink_mb", "downlink", "MB"), ("device_cpu_ms", "device CPU", "ms/frame"),
           ("frames_dropped", "dropped", "frames"),
           # archived keyframes the edge brought back (restore_keyframes)
           ("restores", "restores", "keyframes"),
           # loops the edge closed (loop_closing) and the loop closer's time on one
           ("loops_closed", "loops closed", ""), ("loop_closing_ms", "loop closing", "ms"),
           # steady, consistent poses: an anchor's error on a return, REP 105's odom frame
           # (its jitter, its largest step beyond the truth's), how often the pose came from
           # PnP RANSAC and how many of the device's matches its pose disagreed with
           ("revisit_error_m", "revisit error", "m"),
           ("odom_jitter_rms_mm", "odom jitter RMS", "mm"),
           ("odom_step_excess_mm", "odom step beyond truth", "mm"),
           ("pnp_ransac_share", "PnP-RANSAC fallback", ""),
           ("outlier_share", "outliers of the matches", ""))
#: the figures a paired comparison with the best rule policy is made on (lower is better)
PAIRED = ("tracking_failures", "untracked_frames", "device_failure_share", "ate_m",
          "mean_uncertainty")
#: the rule policies a learned one is compared with
RULE_POLICIES = ("lff", "pu", "adapt", "random")

def side_by_side(results: list[RunResult]) -> list[str]:
    """One line per run: what the device lived through beside what the simulator's rule
    predicted for the same frames, and the camera frames it dropped (the table ``make run``
    prints; a run that dropped any is marked ``!`` and explained below the table). The device
    column names a run's variant (its parameter file and edge; ``-``: none given)."""
    lines = [f"{'policy':<14} {'map source':<10} {'device':<9} {'fails':>5} {'reloc':>5} "
             f"{'restor':>6} {'untrk':>5} {'ATE m':>6} {'RPE m':>6} {'jumps':>5} "
             f"{'max e m':>7} {'jit mm':>6} {'gt jit':>6} {'predicted lost':>14} "
             f"{'device failed':>13} "
             f"{'uploads':>7} {'edge ms':>7} {'dropped':>7}"]
    for r in results:
        rep, cal = r.report, r.calibration
        predicted = f"{cal.predicted_lost_share:.1%}" if cal else "–"
        failed = f"{cal.device_failure_share:.1%}" if cal else "–"
        lines.append(f"{rep.label:<14} {r.key.map_source:<10} {r.variant or '-':<9} "
                     f"{rep.tracking_failures:>5d} {rep.relocalisations:>5d} "
                     f"{rep.restores:>6.0f} "
                     f"{rep.untracked_frames:>5d} {rep.ate_m:>6.3f} "
                     f"{rep.rpe_m:>6.3f} {rep.jumps:>5.0f} {rep.max_error_m:>7.3f} "
                     f"{rep.jitter_rms_mm:>6.1f} {rep.truth_jitter_rms_mm:>6.1f} "
                     f"{predicted:>14} {failed:>13} "
                     f"{rep.frames_uploaded:>7d} {rep.edge_ms_median:>7.0f} {rep.dropped_cell:>7}")
    notes = [note for note in (dropped_frames_note(results), skipped_frames_note(results))
             if note]
    return lines + [f"! {note}" for note in notes]


def dropped_frames_note(results: list[RunResult]) -> str | None:
    """What a reader of the tables must know about runs whose device dropped camera frames
    (it fell behind the camera: the machine was short of CPU), or None when none did. Such a
    run measures the machine as much as the policy — measured on an idle 2-core machine,
    ``--jobs 2`` dropped 75-154 of ~600 frames in every LFF and PU run, and LFF's seed 0
    failed 45 % of its frames there against 15.8 % with ``--jobs 1`` (0 dropped)."""
    dropped, runs = _runs_with(results, lambda r: r.report.frames_dropped)
    if not dropped:
        return None
    return (f"{len(dropped)} of {len(results)} runs dropped camera frames (the device fell "
            f"behind the camera: the machine was short of CPU), and their figures measure the "
            f"machine as much as the policy — {runs}. Run such an evaluation with fewer "
            "--jobs (each run takes about a core).")


def _runs_with(results: list[RunResult], frames: Callable[[RunResult], float]
               ) -> tuple[list[RunResult], str]:
    """The runs with ``frames`` > 0 (NaN: not reported), and them named with their count."""
    chosen = [r for r in results if frames(r) > 0]
    return chosen, "; ".join(f"{r.key.scenario} {r.key.map_source} {r.key.policy} seed "
                             f"{r.key.seed}: {frames(r):.0f}" for r in chosen)


def skipped_frames_note(results: list[RunResult]) -> str | None:
    """The runs in which the player skipped frames it could not read (a corrupt or empty
    image: the data's fault, not the machine's; the device never saw them), or None."""
    skipped, runs = _runs_with(results, lambda r: r.report.frames_skipped)
    if not skipped:
        return None
    return (f"{len(skipped)} of {len(results)} runs played a sequence with unreadable frames, "
            f"which the player skipped (the sequence player's log names the files) — {runs}.")


def agreement_over_runs(results: list[RunResult]) -> dict[str, tuple[float, int]]:
    """Per map source: Pearson's r over runs between the predicted lost share and the
    device's failure share, and how many runs (r is NaN below 3 runs or without spread)."""
    out = {}
    for source in dict.fromkeys(r.key.map_source for r in results):
        pairs = [(r.calibration.predicted_lost_share, r.calibration.device_failure_share)
                 for r in results if r.key.map_source == source and r.calibration is not None
                 and r.calibration.frames]
        predicted, failed = zip(*pairs, strict=True) if pairs else ((), ())
        out[source] = (pearson_r(np.array(predicted), np.array(failed)), len(pairs))
    return out


@dataclass
class SummaryRow:
    scenario: str
    map_source: str
    policy: str
    runs: int
    figures: dict[str, tuple[float, float]]      #: metric → (mean, 95 % half-width)


def figures_of(result: RunResult) -> dict[str, float]:
    """Every figure of :data:`METRICS` one run measured (NaN where it could not)."""
    cal = result.calibration
    shares = {"device_failure_share": cal.device_failure_share if cal else math.nan,
              "predicted_lost_share": cal.predicted_lost_share if cal else math.nan}
    return {m: shares[m] if m in shares else float(getattr(result.report, m))
            for m, _, _ in METRICS}


def summarise(results: list[RunResult]) -> list[SummaryRow]:
    """Mean ± CI over runs per scenario × map source × policy label (a label's training runs
    pooled with its seeds), in the order the runs came."""
    groups: dict[tuple[str, str, str], list[dict[str, float]]] = {}
    for r in results:
        groups.setdefault((r.key.scenario, r.key.map_source, r.key.policy), []).append(
            figures_of(r))
    return [SummaryRow(scenario, source, policy, len(runs),
                       {m: mean_ci95([f[m] for f in runs]) for m, _, _ in METRICS})
            for (scenario, source, policy), runs in groups.items()]


@dataclass(frozen=True)
class PairedRow:
    scenario: str
    map_source: str
    metric: str
    best: str                 #: the rule policy with the lowest mean on this metric
    policy: str
    seeds: int                #: seeds both ran
    difference: float         #: mean over seeds of (policy - best); a label's runs averaged
    ci95: float               #: Student-t half-width over the seeds


def paired_differences(results: list[RunResult]) -> list[PairedRow]:
    """Per scenario, map source and metric of :data:`PAIRED`: every policy against the rule
    policy with the lowest mean, seed by seed (the same walk and uplink draws), a label's
    training runs averaged within a seed first."""
    cells: dict[tuple[str, str], dict[str, dict[int, list[dict[str, float]]]]] = {}
    for r in results:
        cell = cells.setdefault((r.key.scenario, r.key.map_source), {})
        cell.setdefault(r.key.policy, {}).setdefault(r.key.seed, []).append(figures_of(r))
    rows = []
    for (scenario, source), by_policy in cells.items():
        for metric in PAIRED:
            seeds = {p: _per_seed(runs, metric) for p, runs in by_policy.items()}
            rules = [p for p in by_policy if p in RULE_POLICIES and seeds[p]]
            if not rules:
                continue
            best = min(rules, key=lambda p: float(np.mean(list(seeds[p].values()))))
            base = seeds[best]
            for policy in by_policy:
                if policy == best:
                    continue
                mine = seeds[policy]
                common = sorted(set(mine) & set(base))
                d = paired_difference([[mine[s] for s in common]], [base[s] for s in common])
                rows.append(PairedRow(scenario, source, metric, best, policy, len(common),
                                      d.mean, d.high - d.mean))
    return rows


def _per_seed(runs: dict[int, list[dict[str, float]]], metric: str) -> dict[int, float]:
    """A policy's ``metric`` per seed, its runs of the seed averaged (NaN ones left out)."""
    return {seed: float(np.nanmean([f[metric] for f in group]))
            for seed, group in runs.items() if not all(math.isnan(f[metric]) for f in group)}


def paired_markdown(rows: list[PairedRow]) -> str:
    lines = ["| scenario | map source | figure | best rule policy | policy | seeds | "
             "difference (policy - best) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        digits = 3 if r.metric in ("ate_m", "device_failure_share") else 1
        half = "" if math.isnan(r.ci95) else f" ± {r.ci95:.{digits}f}"
        apart = " (CI excludes 0)" if not math.isnan(r.ci95) and abs(r.difference) > r.ci95 \
            else ""
        lines.append(f"| {r.scenario} | {r.map_source} | {r.metric} | {r.best} | {r.policy} | "
                     f"{r.seeds} | {r.difference:+.{digits}f}{half}{apart} |")
    return "\n".join(lines)


def _cell(mean: float, half: float, metric: str) -> str:
    if math.isnan(mean):
        return "–"
    digits = {"ate_m": 3, "rpe_m": 3, "recover_s": 2, "lost_share": 3,
              "device_failure_share": 3, "predicted_lost_share": 3}.get(metric, 1)
    return f"{mean:.{digits}f}" + ("" if math.isnan(half) else f" ± {half:.{digits}f}")


def markdown_table(rows: list[SummaryRow]) -> str:
    titles = [f"{t} ({u})" if u else t for _, t, u in METRICS]
    lines = ["| scenario | map source | policy | runs | " + " | ".join(titles) + " |",
             "|" + "---|" * (4 + len(METRICS))]
    for r in rows:
        cells = [_cell(*r.figures[m], m) for m, _, _ in METRICS]
        lines.append(f"| {r.scenario} | {r.map_source} | {r.policy} | {r.runs} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_summary(rows: list[SummaryRow], out: Path, note: str | None = None) -> None:
    """summary.csv, summary.md (``note`` below the table: the runs that dropped frames) and
    summary.png."""
    header = ["scenario", "map_source", "policy", "runs"] + [
        f"{m}{s}" for m, _, _ in METRICS for s in ("_mean", "_ci95")]
    write_csv(out / "summary.csv", header,
              [[r.scenario, r.map_source, r.policy, r.runs,
                *(v for m, _, _ in METRICS for v in r.figures[m])] for r in rows])
    below = f"\n**Warning.** {note}\n" if note else ""
    (out / "summary.md").write_text(markdown_table(rows) + "\n" + below, encoding="utf-8")
    plot(rows, out / "summary.png")


def write_paired(rows: list[PairedRow], out: Path) -> None:
    write_csv(out / "paired.csv", [f.name for f in fields(PairedRow)],
              [list(asdict(r).values()) for r in rows])
    (out / "paired.md").write_text(paired_markdown(rows) + "\n", encoding="utf-8")


def plot(rows: list[SummaryRow], path: Path) -> None:
    """Grouped bars (scenario groups, one bar per policy) with 95 % CIs, one panel per figure
    a user weighs: ATE, failures, untracked frames, the device's failure share beside the
    simulator's predicted lost share, mean υ."""
    plt = pyplot()
    panels = ("ate_m", "tracking_failures", "untracked_frames", "device_failure_share",
              "predicted_lost_share", "mean_uncertainty")
    sources = {r.map_source for r in rows}

    def group(r: SummaryRow) -> str:
        return r.scenario if len(sources) == 1 else f"{r.scenario}\n{r.map_source}"

    scenarios = list(dict.fromkeys(group(r) for r in rows))
    policies = list(dict.fromkeys(r.policy for r in rows))
    width = 0.8 / max(len(policies), 1)
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
    for ax, metric in zip(axes.ravel(), panels, strict=True):
        _, title, unit = next(m for m in METRICS if m[0] == metric)
        for j, policy in enumerate(policies):
            xs, means, halves = [], [], []
            for i, scenario in enumerate(scenarios):
                row = next((r for r in rows if group(r) == scenario and r.policy == policy),
                           None)
                if row is not None:
                    mean, half = row.figures[metric]
                    xs.append(i + (j - (len(policies) - 1) / 2) * width)
                    means.append(mean)
                    halves.append(0.0 if math.isnan(half) else half)
            ax.bar(xs, means, width, yerr=halves, capsize=3, label=policy)
        ax.set_xticks(range(len(scenarios)), scenarios, rotation=15)
        ax.set_title(f"{title} ({unit})" if unit else title)
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].legend()
    fig.suptitle("live pipeline per scenario" + (" and device map source" if len(sources) > 1
                 else f" ({next(iter(sources))} map source)") + " and policy: mean and 95 % "
                 "CI over seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
