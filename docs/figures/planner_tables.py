"""The planner tables of docs/results/planning.md and the controls of
docs/results/learning.md, from ``twinslam sim
--csv`` files (each command is on those pages beside its table): per policy the mean υ (a lost
frame scoring 0) ± 95 % CI over the episodes, the lost share, υ over the tracked frames
(pooled), and the paired difference with
the best rule policy on the same episodes; with a ``reference`` row, also the share of the
best rule's gap to the reference that each policy closes (a bootstrap over episodes).

Several files of the same episodes (the same --covis, --seeds, --seed0, --slots and channel)
may be given: their rows are pooled, each (policy, seed) once.

    .venv/bin/python docs/figures/planner_tables.py FILE.csv [FILE.csv …] [--against POLICY]
        [--rows POLICY,POLICY,…]
    .venv/bin/python docs/figures/planner_tables.py learning-curve FOLDER

``learning-curve FOLDER``: the controls table and the paired comparisons that ``twinslam
experiment learning-curve --out FOLDER`` wrote, as markdown.

``--against POLICY`` pairs every policy with that one instead of the best rule (the
ablations: each variant against the planner it varies). ``--rows`` prints those policies
alone, in that order (a table of those pages that shows some of the files' policies).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from twinslam.reporting import mean_ci95, paired_difference

RULES = ("lff", "pu", "adapt")


def episodes(paths: list[Path]) -> dict[str, dict[int, dict[str, float]]]:
    """policy → seed → {mean, lost, tracked}, pooled over the files."""
    out: dict[str, dict[int, dict[str, float]]] = {}
    for path in paths:
        with path.open(encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                out.setdefault(row["policy"], {})[int(row["seed"])] = {
                    "mean": float(row["mean_uncertainty"]), "lost": float(row["lost_share"]),
                    "tracked": float(row["tracked_uncertainty"])}
    return out


def tracked(runs: dict[int, dict[str, float]], seeds: list[int]) -> float:
    """υ over the tracked frames of all the episodes: each episode's tracked mean weighted by
    its tracked share (every episode has as many frames), so mean υ = (1 - lost) · tracked
    holds for the pooled figures too."""
    kept = np.array([1.0 - runs[s]["lost"] for s in seeds])
    values = np.array([runs[s]["tracked"] if kept[i] > 0 else 0.0
                       for i, s in enumerate(seeds)])
    return float((kept * values).sum() / kept.sum()) if kept.sum() > 0 else float("nan")


def gap_closed(policy: np.ndarray, best: np.ndarray, reference: np.ndarray,
               draws: int = 4000, seed: int = 0) -> tuple[float, float, float]:
    """(best − policy) / (best − reference) over the episodes' means, and its 95 % bootstrap
    interval (episodes drawn with replacement)."""
    rng = np.random.default_rng(seed)
    n = policy.size
    picks = rng.integers(0, n, size=(draws, n))
    gap = (best[picks].mean(1) - reference[picks].mean(1))
    closed = (best[picks].mean(1) - policy[picks].mean(1)) / np.where(gap == 0, np.nan, gap)
    value = (best.mean() - policy.mean()) / (best.mean() - reference.mean())
    low, high = np.nanpercentile(closed, [2.5, 97.5])
    return float(value), float(low), float(high)


def table(paths: list[Path], against: str | None = None,
          rows: list[str] | None = None) -> str:
    by = episodes(paths)
    missing = [p for p in rows or [] if p not in by]
    if missing:
        raise SystemExit(f"--rows {', '.join(missing)}: no such policy in {', '.join(by)}")
    seeds = sorted(set.intersection(*(set(v) for v in by.values())))
    mean = {p: np.array([by[p][s]["mean"] for s in seeds]) for p in by}
    lost = {p: np.array([by[p][s]["lost"] for s in seeds]) for p in by}
    best = against or min((p for p in RULES if p in mean), key=lambda p: mean[p].mean())
    if best not in mean:
        raise SystemExit(f"--against {best}: no such policy in {', '.join(mean)}")
    reference = mean.get("reference") if against is None else None
    head = ["policy", "mean υ ± 95 % CI", "lost (%)", "υ tracked", f"paired vs {best}",
            f"lost (pts) vs {best}"]
    if reference is not None:
        head.append("gap to the reference closed")
    lines = [f"{', '.join(p.name for p in paths)}: {len(seeds)} episodes (seeds "
             f"{seeds[0]}–{seeds[-1]}); paired: mean [95 % CI, Student's t] over the "
             "same episodes", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in rows or list(by):
        m, ci = mean_ci95(mean[p].tolist())
        d = paired_difference(mean[p][None, :], mean[best])
        dl = paired_difference(100 * lost[p][None, :], 100 * lost[best])
        cells = [p, f"{m:.1f} ± {ci:.1f}", f"{100 * lost[p].mean():.2f}",
                 f"{tracked(by[p], seeds):.1f}",
                 "—" if p == best else f"{d.mean:+.1f} [{d.low:+.1f}, {d.high:+.1f}]",
                 "—" if p == best else f"{dl.mean:+.2f} [{dl.low:+.2f}, {dl.high:+.2f}]"]
        if reference is not None:
            if p in (best, "reference"):
                cells.append("—")
            else:
                v, lo, hi = gap_closed(mean[p], mean[best], reference)
                cells.append(f"{100 * v:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def curve_tables(folder: Path) -> str:
    """The learning curve's controls table and its paired comparisons (``twinslam experiment
    learning-curve`` wrote both CSVs into ``folder``) as markdown."""
    with (folder / "learning_curve_controls.csv").open(encoding="utf-8") as fh:
        controls = list(csv.DictReader(fh))
    with (folder / "learning_curve_paired.csv").open(encoding="utf-8") as fh:
        paired = list(csv.DictReader(fh))
    best = controls[0]["best_rule"] if controls else ""
    lines = ["| policy | training runs | episodes | mean υ ± 95 % CI | lost (%) | υ tracked | "
             f"paired vs {best} |", "|---|---|---|---|---|---|---|"]
    for r in controls:
        ci = float(r["ci95"])
        diff = ("—" if r["paired_vs_best_rule"] == "" else
                f"{float(r['paired_vs_best_rule']):+.1f} [{float(r['paired_ci_low']):+.1f}, "
                f"{float(r['paired_ci_high']):+.1f}]")
        lines.append(f"| {r['policy']} | {r['training_runs'] or '—'} | {r['episodes']} | "
                     f"{float(r['mean_uncertainty']):.1f} ± "
                     f"{'n/a' if np.isnan(ci) else f'{ci:.1f}'} | "
                     f"{100 * float(r['lost_share']):.2f} | "
                     f"{float(r['tracked_uncertainty']):.1f} | {diff} |")
    lines += ["", "| comparison (paired by episode) | runs | mean difference [95 % CI] | "
              "told apart |", "|---|---|---|---|"]
    for r in paired:
        lines.append(f"| {r['comparison']} | {r['runs']} | {float(r['mean_difference']):+.1f} "
                     f"[{float(r['ci_low']):+.1f}, {float(r['ci_high']):+.1f}] | "
                     f"{'yes' if r['apart'] == 'True' else 'no'} |")
    return "\n".join(lines)


def main(argv: list[str]) -> None:
    if argv[:1] == ["learning-curve"] and len(argv) == 2:
        print(curve_tables(Path(argv[1])))
        return
    parser = argparse.ArgumentParser(
        prog="planner_tables.py", description=__doc__.split("\n\n")[0],
        epilog="or: planner_tables.py learning-curve FOLDER (the learning curve's tables)")
    parser.add_argument("csv", nargs="+", type=Path,
                        help="`twinslam sim --csv` files of the same episodes")
    parser.add_argument("--against", metavar="POLICY",
                        help="pair every policy with this one (default: the best rule)")
    parser.add_argument("--rows", metavar="POLICY,POLICY,…",
                        help="print these policies alone, in this order (default: all)")
    args = parser.parse_args(argv)
    rows = [r.strip() for r in args.rows.split(",")] if args.rows else None
    print(table(args.csv, args.against, rows))


if __name__ == "__main__":
    main(sys.argv[1:])
