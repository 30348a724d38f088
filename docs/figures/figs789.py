"""The Figs 7–9 files of docs/results/learning.md, from the CSVs ``twinslam experiment
fig7|fig8|fig9``
wrote (every table and figure of the map-management part comes from a committed
command):

    .venv/bin/python docs/figures/figs789.py table docs/figures/fig7.csv     # the markdown table
    .venv/bin/python docs/figures/figs789.py paired docs/figures/figs-with-controls/fig7/fig7.csv
    .venv/bin/python docs/figures/figs789.py redraw docs/figures/fig7.csv    # fig7.png beside it
    .venv/bin/python docs/figures/figs789.py fig8-join docs/figures          # fig8.csv, fig8.png

``table``: one row per policy, one column per x, each cell "mean υ ± 95 % CI · lost share · υ
over the tracked frames" (the bound: mean ± CI only). ``paired``: each policy's paired
difference with the best rule at each x, "mean [95 % CI]" (the columns the experiment
writes since the controls were added; a CSV without them is refused). ``redraw``: the figure
as the experiment draws it (``amm.plot_figure``), from the CSV alone. ``fig8-join``:
fig8.csv from fig8_n2.csv and fig8_n4.csv — the file one ``twinslam experiment fig8``
process writes when the two N were run as separate processes (as docs/results/learning.md's were).
"""

from __future__ import annotations

import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

from twinslam.experiments.amm import BOUND, COLUMNS, plot_figure


@dataclass(frozen=True)
class Row:
    """What the figure and the table read of one (x, policy) row."""

    mean: float
    ci95: float
    lost_share: float
    tracked_uncertainty: float
    best_rule: str = ""                                #: at this x ("" in a CSV without controls)
    paired: tuple[float, float, float] | None = None   #: vs best_rule: mean, CI low, high


def read(path: Path) -> tuple[str, dict[str, dict[str, Row]]]:
    """(x label, x → policy → row) of a figure CSV, in file order."""
    with path.open(encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        x_label = (reader.fieldnames or [""])[0]
        out: dict[str, dict[str, Row]] = {}
        for r in reader:
            paired = (None if not r.get("paired_vs_best_rule") else
                      (float(r["paired_vs_best_rule"]), float(r["paired_ci_low"]),
                       float(r["paired_ci_high"])))
            out.setdefault(r[x_label], {})[r["policy"]] = Row(
                float(r["mean_uncertainty"]), float(r["ci95"]),
                float(r["lost_share"] or "nan"), float(r["tracked_uncertainty"] or "nan"),
                r.get("best_rule", ""), paired)
    return x_label, out


def _num(value: float) -> str:
    return f"{value:.1f}".replace("-", "−")


def table(path: Path) -> str:
    x_label, by_x = read(path)
    xs = list(by_x)
    policies = list(dict.fromkeys(p for x in xs for p in by_x[x]))
    lines = ["| policy | " + " | ".join(f"{x_label} {x}" for x in xs) + " |",
             "|---" * (len(xs) + 1) + "|"]
    for policy in policies:
        cells = []
        for x in xs:
            r = by_x[x].get(policy)
            if r is None:
                cells.append("—")
            elif policy == BOUND or math.isnan(r.lost_share):
                cells.append(f"{_num(r.mean)} ± {r.ci95:.1f}")
            else:
                cells.append(f"{_num(r.mean)} ± {r.ci95:.1f} · {100 * r.lost_share:.1f} % · "
                             f"{_num(r.tracked_uncertainty)}")
        lines.append(f"| {policy} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def paired(path: Path) -> str:
    """Each policy minus the best rule policy at each x, on the same episodes (a two-level
    bootstrap over training runs and episodes: ``twinslam experiment`` computed it)."""
    x_label, by_x = read(path)
    xs = list(by_x)
    best = {x: next(iter(by_x[x].values())).best_rule for x in xs}
    if not all(best.values()):
        raise SystemExit(f"{path}: no paired columns (written before the controls were added)")
    lines = ["| paired with the best rule | " + " | ".join(
        f"{x_label} {x} (vs {best[x]})" for x in xs) + " |", "|---" * (len(xs) + 1) + "|"]
    for policy in dict.fromkeys(p for x in xs for p in by_x[x]):
        cells = []
        for x in xs:
            r = by_x[x].get(policy)
            if r is None or r.paired is None or policy == best[x]:
                cells.append("—")
            else:
                d, low, high = r.paired
                cells.append(f"{d:+.1f} [{low:+.1f}, {high:+.1f}]".replace("-", "−"))
        if any(c != "—" for c in cells):
            lines.append(f"| {policy} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def redraw(path: Path) -> Path:
    x_label, by_x = read(path)
    png = path.with_suffix(".png")
    results = {_x(x): dict(rows) for x, rows in by_x.items()}
    plot_figure(png, results, x_label, bars=path.stem == "fig8")  # type: ignore[arg-type]
    return png


def _x(x: str) -> float | int:
    value = float(x)
    return int(value) if value.is_integer() else value


def fig8_join(folder: Path) -> Path:
    rows: list[list[str]] = []
    header: list[str] = []
    for part in sorted(folder.glob("fig8_n*.csv")):
        if part.stem.endswith("_runs"):
            continue
        with part.open(encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader)
            rows += list(reader)
    if not rows:
        raise SystemExit(f"{folder}: no fig8_nN.csv files")
    if header[1:] != COLUMNS[:len(header) - 1]:
        raise SystemExit(f"unexpected fig8 columns {header}")
    out = folder / "fig8.csv"
    with out.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)
    redraw(out)
    return out


def main() -> None:
    if len(sys.argv) != 3 or sys.argv[1] not in ("table", "paired", "redraw", "fig8-join"):
        raise SystemExit(__doc__)
    command, target = sys.argv[1], Path(sys.argv[2])
    if command == "table":
        print(table(target))
    elif command == "paired":
        print(paired(target))
    elif command == "redraw":
        print(f"wrote {redraw(target)}")
    else:
        print(f"wrote {fig8_join(target)} and fig8.png")


if __name__ == "__main__":
    main()
