"""``twinslam calibrate``: the rule of a lost frame measured from evaluate's runs."""

from __future__ import annotations

import argparse
from dataclasses import asdict, fields
from pathlib import Path

from twinslam.cli.console import Subparsers, error
from twinslam.reporting import write_csv

#: where the figure goes in the first folder, its tables beside it (.csv, .md, -failures.csv):
#: never evaluate's own calibration.csv, which holds the runs this command reads
DEFAULT_FIGURE = "rule-calibration.png"
#: what evaluate wrote in a folder and calibrate reads: never written over
EVALUATE_FILES = ("calibration.csv", "calibration_frames.csv", "runs.csv")


def run(args: argparse.Namespace) -> int:
    # scipy and matplotlib load with the command, not with every `twinslam` start
    from twinslam.live.calibration.report import (
        FailureCauses,
        ScenarioAgreement,
        agreement_by_scenario,
        agreement_markdown,
        calibrate_runs,
        failure_causes,
        failure_causes_markdown,
        plot_calibration,
        read_rows,
        report_lines,
    )

    try:
        runs = read_rows(args.folders, "calibration.csv")
        frames = read_rows(args.folders, "calibration_frames.csv")
        results = calibrate_runs(runs, frames)
        agreement = agreement_by_scenario(runs)
    except (FileNotFoundError, KeyError, ValueError) as exc:
        return error(exc)
    try:
        causes: list[FailureCauses] | None = failure_causes(frames)
    except ValueError as exc:        # frames of an older evaluate: the rest still stands
        print(f"no failure causes: {exc}")
        causes = None
    if not results:
        return error("no calibrated next-slot frame in those folders")
    for line in report_lines(results):
        print(line)
    table = agreement_markdown(agreement)
    print("\nper map source and scenario (shares and measures: mean over runs):")
    print(table)
    out = args.out or args.folders[0] / DEFAULT_FIGURE
    inputs = {(f / name).resolve() for f in args.folders for name in EVALUATE_FILES}
    clash = sorted(str(p) for p in (out, out.with_suffix(".csv"), out.with_suffix(".md"),
                                    out.with_name(f"{out.stem}-failures.csv"))
                   if p.resolve() in inputs)
    if clash:
        return error(f"--out {out} would overwrite {', '.join(clash)}, which evaluate wrote "
                     "and calibrate reads; name another figure")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return error(f"--out {out}: cannot make its folder: {exc}")
    plot_calibration(runs, frames, results, out)
    write_csv(out.with_suffix(".csv"), [f.name for f in fields(ScenarioAgreement)],
              [list(asdict(a).values()) for a in agreement])
    markdown, written = table, [str(out), str(out.with_suffix(".csv"))]
    if causes is not None:
        causes_table = failure_causes_markdown(causes)
        print("\nwhere the failed frames come from (share of the scored frames, count):")
        print(causes_table)
        write_csv(out.with_name(f"{out.stem}-failures.csv"),
                  [f.name for f in fields(FailureCauses)],
                  [list(asdict(c).values()) for c in causes])
        markdown += f"\n\n{causes_table}"
        written.append(f"{out.stem}-failures.csv")
    out.with_suffix(".md").write_text(markdown + "\n", encoding="utf-8")
    print(f"wrote {', '.join(written)} and {out.with_suffix('.md')}")
    return 0


def register(sub: Subparsers) -> None:
    calibrate = sub.add_parser(
        "calibrate", help="the rule of a lost frame, measured from `twinslam evaluate` runs: "
        "lag, threshold, agreement per run and per scenario, where the failed frames come from "
        "(rule-calibration.png, .csv, -failures.csv, .md)")
    calibrate.add_argument("folders", nargs="+", type=Path,
                           help="output folders of `twinslam evaluate` (calibration.csv and "
                           "calibration_frames.csv in each)")
    calibrate.add_argument("--out", type=Path, default=None,
                           help="the figure to write, the table beside it as .csv and .md "
                           "(default: FIRST_FOLDER/rule-calibration.png; never one of "
                           "evaluate's files)")
    calibrate.set_defaults(func=run)
