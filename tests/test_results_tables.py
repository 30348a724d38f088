"""The tables of the results pages (docs/results/*.md) are printed by committed commands from
committed CSVs: re-running each command written beside a table must print that table. A page
edited by hand, or a CSV re-run without its table, fails here."""

from __future__ import annotations

import csv
import gzip
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[1]
FIGURES = REPO / "docs" / "figures"
#: every results page, the findings page first
RESULTS = "\n".join(path.read_text(encoding="utf-8") for path in
                    [REPO / "docs" / "results.md",
                     *sorted((REPO / "docs" / "results").glob("*.md"))])

MPC_ABLATIONS = ("mpc:H=2,mpc:H=1,mpc,mpc:H=2/S=1,mpc:H=2/frames=persistence,"
                 "mpc:H=2/frames=oracle,mpc:H=2/rates=last,mpc:H=2/rates=markov,"
                 "mpc:H=2/rates=variational,mpc:H=2/rates=oracle,"
                 "mpc:H=2/rates=oracle/frames=oracle")
#: planner_tables.py's arguments, as the results pages write them beside each table
PLANNER_TABLES = [
    ["planner/mpc-tune.csv"],
    ["planner/mpc-eval-*.csv", "--rows", "lff,pu,adapt,random,mpc:H=2,reference"],
    ["planner/mpc-eval-*.csv", "--against", "mpc:H=2", "--rows", MPC_ABLATIONS],
    ["planner/mpc-nonstationary-*.csv", "--against", "mpc", "--rows",
     "lff,mpc:rates=last,mpc:rates=markov,mpc,mpc:rates=variational,mpc:rates=oracle"],
    ["learning-curve", "learning-curves/actor"],
    ["learning-curve", "learning-curves/residual"],
    ["learning-curve", "learning-curves/residual-12k"],
]
#: figs789.py's (mode, CSV) pairs
FIGURE_TABLES = [("table", "fig7.csv"), ("table", "fig8.csv"), ("table", "fig9.csv")] + [
    (mode, f"figs-with-controls/fig{n}/fig{n}.csv") for n in (7, 8, 9)
    for mode in ("table", "paired")]


def _script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, FIGURES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module            # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _expand(args: list[str]) -> list[str]:
    """The shell's globbing, relative to docs/figures (sorted, as bash does)."""
    out: list[str] = []
    for arg in args:
        if "*" in arg:
            out += sorted(str(p) for p in FIGURES.glob(arg))
        elif arg.endswith(".csv") or (FIGURES / arg).is_dir():   # a file or folder of figures
            out.append(str(FIGURES / arg))
        else:
            out.append(arg)
    return out


def _tables(printed: str) -> list[list[str]]:
    """The markdown tables of a printout: each run of consecutive ``|`` lines, stripped."""
    tables: list[list[str]] = []
    previous_was_row = False
    for line in printed.splitlines():
        row = line.strip().startswith("|")
        if row and previous_was_row:
            tables[-1].append(line.strip())
        elif row:
            tables.append([line.strip()])
        previous_was_row = row
    return tables


RESULT_LINES = [line.strip() for line in RESULTS.splitlines()]


def _missing(printed: str) -> list[list[str]]:
    """The printed tables that the results pages do not hold as they are printed: every table
    of the printout must stand on a page as one block, its header, separator and rows in
    that order and nothing between them (a row of another table is not this table). A
    printout without a table is missing too."""
    tables = _tables(printed)
    if not tables:
        return [["(no table printed)"]]
    missing = []
    for table in tables:
        if len(table) < 3 or not set(table[1]) <= set("|-: "):
            missing.append(["(not a table: no header, separator and row)", *table])
            continue
        if not _on_a_page(table):
            missing.append(table)
    return missing


def _on_a_page(lines: list[str]) -> bool:
    """Whether the results pages hold ``lines`` one after another, as they are."""
    n = len(lines)
    return any(RESULT_LINES[i:i + n] == lines for i in range(len(RESULT_LINES) - n + 1))


@pytest.mark.parametrize("args", PLANNER_TABLES, ids=lambda a: " ".join(a)[:60])
def test_each_planner_table_is_what_its_command_prints(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    _script("planner_tables").main(_expand(args))
    assert _missing(capsys.readouterr().out) == []


@pytest.mark.parametrize(("mode", "csv"), FIGURE_TABLES)
def test_each_figure_table_is_what_its_command_prints(
        mode: str, csv: str, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["figs789.py", mode, str(FIGURES / csv)])
    _script("figs789").main()
    assert _missing(capsys.readouterr().out) == []


def test_a_row_that_is_not_in_the_files_is_refused() -> None:
    with pytest.raises(SystemExit, match="--rows mpc:H=9: no such policy"):
        _script("planner_tables").main(_expand(["planner/mpc-eval-main.csv", "--rows",
                                                "lff,mpc:H=9"]))


#: archive_restores.py's (without, with restores) runs.csv pairs
ARCHIVE_TABLES = [("archive-restores/revisit-v15-lff-restore0-runs.csv",
                   "archive-restores/revisit-v15-lff-restore3-runs.csv"),
                  ("archive-restores/all-rules-none-runs.csv",
                   "archive-restores/all-rules-restores-runs.csv"),
                  ("archive-restores/failure-causes/none/runs.csv",
                   "archive-restores/failure-causes/restores/runs.csv"),
                  ("slot-length/slot30-dreq025-none/runs.csv",
                   "slot-length/slot30-dreq025-restores/runs.csv")]


@pytest.mark.parametrize(("without", "with_restores"), ARCHIVE_TABLES)
def test_each_archive_restores_table_is_what_its_command_prints(
        without: str, with_restores: str, capsys: pytest.CaptureFixture[str]) -> None:
    _script("archive_restores").main(FIGURES / without, FIGURES / with_restores)
    printed = capsys.readouterr().out
    assert len(_tables(printed)) == 1 and _missing(printed) == []


#: the folders (docs/figures/…/NAME, frames gzipped) the results pages run `twinslam calibrate` on
CALIBRATED_FOLDERS = [("archive-restores/failure-causes", ("none", "restores")),
                      ("default-device", ("table-i-300",)),
                      ("slot-length", ("slot30-dreq025-none", "slot30-dreq025-restores",
                                       "slot30-restores"))]


@pytest.mark.parametrize(("where", "names"), CALIBRATED_FOLDERS, ids=lambda x: str(x)[:40])
def test_the_failure_causes_tables_are_what_calibrate_prints_from_their_frames(
        where: str, names: tuple[str, ...], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """`twinslam calibrate FOLDER...` on the committed frames (gzipped) prints the
    calibration and failure-cause tables the results pages show (and, where committed, the CSV
    beside them)."""
    import gzip

    from twinslam.cli.main import main
    committed = FIGURES / where
    folders = []
    for name in names:
        folder = tmp_path / name
        folder.mkdir()
        (folder / "calibration.csv").write_bytes((committed / name / "calibration.csv")
                                                 .read_bytes())
        (folder / "calibration_frames.csv").write_bytes(
            gzip.decompress((committed / name / "calibration_frames.csv.gz").read_bytes()))
        folders.append(str(folder))
    assert main(["calibrate", *folders, "--out", str(tmp_path / "calibration.png")]) == 0
    printed = capsys.readouterr().out
    assert len(_tables(printed)) == 2 and _missing(printed) == []
    # the committed CSV names each folder as the pages' commands do
    if (committed / "calibration-failures.csv").is_file():
        assert ((tmp_path / "calibration-failures.csv").read_text(encoding="utf-8")
                .replace(f"{tmp_path}/", "")
                == (committed / "calibration-failures.csv").read_text(encoding="utf-8"))


@pytest.mark.parametrize("folder", ["planner/mpc-live", "planner/mpc-live-2"])
def test_the_live_planner_tables_are_what_evaluate_prints_from_their_runs(
        folder: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`twinslam evaluate … --resume` on the committed runs.csv runs nothing — nor extracts the
    played frames' covisibility, which only runs still to do need — and prints the tables
    docs/results/planning.md shows for `mpc` live (the evaluation, and its re-run)."""
    from twinslam.cli.main import main
    for name in ("runs.csv", "calibration.csv"):
        (tmp_path / name).write_bytes((FIGURES / folder / name).read_bytes())
    code = main(["evaluate", "--policy", "lff,mpc:H=2,delay:0.3:lff", "--scenario",
                 "forward,revisit-v15", "--seeds", "10", "--start", "300", "--frames", "300",
                 "--map-source", "edge", "--params", "config/paper-table1.yaml",
                 "--out", str(tmp_path), "--resume"])
    printed = capsys.readouterr().out
    assert code == 0 and "resuming: 60 of 60 runs" in printed, printed[-2000:]
    assert "extracting" not in printed and not (tmp_path / "covis").exists()  # nothing to run
    rows = [line for line in printed.splitlines() if line.startswith("| ")]
    # 2 scenarios x 3 policies, 2 x 2 policies x 5 paired figures, and the two headers
    assert len(rows) == 6 + 20 + 2 and len(_tables(printed)) == 2 and _missing(printed) == []


def test_a_table_is_matched_as_a_whole_and_an_empty_printout_is_not_a_table() -> None:
    """The check itself: a printout with no table fails, and so does a table whose rows all
    stand on a page but in another table, or in another order."""
    assert _missing("nothing printed") == [["(no table printed)"]]
    first, second = [t for t in _tables(RESULTS) if len(t) >= 4 and t[2] != t[3]][:2]
    assert _missing("\n".join(first)) == []
    swapped = [first[0], first[1], first[3], first[2], *first[4:]]
    assert _missing("\n".join(swapped)) == [swapped]
    mixed = [*first[:3], second[2]]
    assert _missing("\n".join(mixed)) == [mixed]


#: device_variants.py's LABEL=FOLDER arguments (folders under docs/figures/own-map), as
#: the results pages write them beside each table
DEVICE_VARIANT_TABLES = [
    ["paper=constrained-restores", "own-map=constrained-own-map",
     "edge+local=constrained-edge-local"],
    ["table-i=revisit-1000-table1", "own-map=revisit-1000-own-map",
     "short-loop=revisit-1000-short-loop", "short-loop+own-map=revisit-1000-short-loop-own-map",
     "edge+local=revisit-1000-edge-local"],
    ["own-map=constrained-1000-own-map"],
    ["table-i=revisit-v25-300-table1", "short-loop+own-map=revisit-v25-300-short-loop-own-map"],
    ["table-i=outages-300-table1", "short-loop+own-map=outages-300-short-loop-own-map"],
]


@pytest.mark.parametrize("args", DEVICE_VARIANT_TABLES, ids=lambda a: a[0])
def test_each_device_variant_table_is_what_its_command_prints(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    module = _script("device_variants")
    module.main([(label, FIGURES / "own-map" / folder)
                 for label, folder in (a.split("=", 1) for a in args)])
    assert _missing(capsys.readouterr().out) == []


#: device_variants.py's LABEL=FOLDER arguments with folders from the repository's root, as
#: docs/results/update-loop.md's "The whole walk on every scenario" writes them
WHOLE_WALK_TABLES = [
    ["table-i=docs/figures/own-map/revisit-1000-table1",
     "table-i+restores=docs/figures/whole-walk/revisit-1000-table1-restores",
     "short-loop=docs/figures/own-map/revisit-1000-short-loop"],
    ["table-i=docs/figures/whole-walk/revisit-v25-1000-table1",
     "short-loop+own-map=docs/figures/whole-walk/revisit-v25-1000-short-loop-own-map",
     "edge+local=docs/figures/whole-walk/revisit-v25-1000-edge-local"],
    ["table-i=docs/figures/whole-walk/outages-1000-table1",
     "short-loop+own-map=docs/figures/whole-walk/outages-1000-short-loop-own-map",
     "edge+local=docs/figures/whole-walk/outages-1000-edge-local"],
    # the depth read as the colour camera's, and registered to 7-Scenes' colour camera
    ["depth-camera=docs/figures/colour-camera/revisit-1000-short-loop-own-map",
     "colour-camera=docs/figures/colour-camera/revisit-1000-short-loop-own-map-colour"],
    ["edge+local=docs/figures/own-map/revisit-1000-edge-local",
     "edge+local+colour=docs/figures/colour-camera/revisit-1000-edge-local-colour"],
    ["depth-camera=docs/figures/whole-walk/revisit-v25-1000-short-loop-own-map",
     "colour-camera=docs/figures/colour-camera/revisit-v25-1000-short-loop-own-map-colour"],
    ["depth-camera=docs/figures/whole-walk/outages-1000-short-loop-own-map",
     "colour-camera=docs/figures/colour-camera/outages-1000-short-loop-own-map-colour"],
]


@pytest.mark.parametrize("args", WHOLE_WALK_TABLES, ids=lambda a: a[1].split("/")[-1])
def test_each_whole_walk_table_is_what_its_command_prints(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    module = _script("device_variants")
    module.main([(label, REPO / folder) for label, folder in (a.split("=", 1) for a in args)])
    assert _missing(capsys.readouterr().out) == []


#: device_variants.py --user's arguments of docs/results/any-uplink.md: Theorem 1 exactly
#: against the progress rule, one folder each, one scenario of it a table
PROGRESS_TABLES = [[f"theorem1-exact=docs/figures/progress-uploads/theorem1-exact#{scenario}",
                    f"progress=docs/figures/progress-uploads/with-progress#{scenario}"]
                   for scenario in ("revisit-v15@constrained", "revisit-v15@lte")]


#: the pilot of the default-device sweep, as docs/results/any-uplink.md writes its command
PILOT_TABLES = [[f"{label}=docs/figures/default-device/pilot-300/{folder}-300#{scenario}"
                 for label, folder in (("table-i", "table-i"),
                                       ("short-loop-own-map", "short-loop-own-map"),
                                       ("edge+local", "edge-local"))]
                for scenario in ("revisit-v15@table1", "revisit-v15@lte", "revisit-v15@mmwave",
                                 "revisit-v15@constrained", "outages@lte")]


#: the whole walk of the default-device sweep, ten seeds
WALK_TABLES = [[f"{label}=docs/figures/default-device/{folder}-1000#{scenario}"
                for label, folder in (("table-i", "table-i"),
                                      ("short-loop-own-map", "short-loop-own-map"),
                                      ("edge+local", "edge-local"))]
               for scenario in ("revisit-v15@table1", "revisit-v15@lte", "revisit-v15@mmwave",
                                "revisit-v15@constrained")]


#: the default-device sweep's revisits and outages, 300 frames forward and back, ten seeds
SCENARIO_TABLES = [[f"{label}=docs/figures/default-device/{folder}-300#{scenario}"
                    for label, folder in (("table-i", "table-i"),
                                          ("short-loop-own-map", "short-loop-own-map"),
                                          ("edge+local", "edge-local"))]
                   for scenario in ("revisit-v25@table1", "revisit-v25@lte", "revisit-v25@mmwave",
                                    "revisit-v25@constrained", "outages@lte",
                                    "outages@constrained")]


@pytest.mark.parametrize("args", PROGRESS_TABLES + PILOT_TABLES + WALK_TABLES + SCENARIO_TABLES,
                         ids=lambda a: a[0].split("/")[-1])
def test_each_progress_rule_and_pilot_table_is_what_its_command_prints(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    module = _script("device_variants")
    module.main([(label, REPO / folder) for label, folder in (a.split("=", 1) for a in args)],
                user=True)
    assert _missing(capsys.readouterr().out) == []


#: device_variants.py --steady's arguments: the point fusion's runs, loop closing's
STEADY_TABLES = [[f"{name}=docs/figures/point-fusion/{name}#revisit-v15@lte"
                  for name in ("no-fusion", "fusion")],
                 [f"{name}=docs/figures/loop-closing/{name}#revisit-v15@lte"
                  for name in ("no-loops", "loops-20-inliers", "loops")]]


@pytest.mark.parametrize("args", STEADY_TABLES, ids=lambda a: a[0].split("/")[-1])
def test_each_steadiness_table_is_what_its_command_prints(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    module = _script("device_variants")
    module.main([(label, REPO / folder) for label, folder in (a.split("=", 1) for a in args)],
                steady=True)
    assert _missing(capsys.readouterr().out) == []


def test_the_starved_slots_table_is_what_its_command_prints(
        capsys: pytest.CaptureFixture[str]) -> None:
    """docs/figures/default-device/starved_slots.py on the default device's folder: every
    stretch without an upload beside the uplink's stretch under α."""
    _script("default-device/starved_slots").main(
        [str(FIGURES / "default-device" / "edge-local-300")])
    assert _missing(capsys.readouterr().out) == []


def test_a_device_variant_folder_without_the_scenario_asked_for_is_refused() -> None:
    module = _script("device_variants")
    with pytest.raises(SystemExit, match="no run of scenario revisit-v25@lte"):
        module.main([("x", REPO / "docs/figures/progress-uploads/with-progress#revisit-v25@lte")])


def test_the_uplink_families_table_is_what_its_command_prints(
        capsys: pytest.CaptureFixture[str]) -> None:
    _script("uplink_families_table").main(["--seeds", "10", "--minutes", "10"])
    assert _missing(capsys.readouterr().out) == []


def test_the_error_along_the_walk_table_is_what_its_command_prints() -> None:
    """The bins of every tracked frame's error: two front-end walks and four live folders."""
    module = _script("error_along_the_walk")
    inputs = {"front-end": "trajectory-error/front-end-depth-camera.csv",
              "front-end+colour": "trajectory-error/front-end-colour-camera.csv",
              "paper-device": "own-map/revisit-1000-short-loop-own-map",
              "paper-device+colour": "colour-camera/revisit-1000-short-loop-own-map-colour",
              "edge+local": "own-map/revisit-1000-edge-local",
              "edge+local+colour": "colour-camera/revisit-1000-edge-local-colour"}
    errors = {}
    for label, path in inputs.items():
        errors.update(module.read_errors(label, FIGURES / path))
    assert _missing(module.table(errors, 100)) == []


def test_the_ate_floor_table_is_what_its_command_prints(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The floor of the walk's ATE: two cameras, the whole walk and its first half; three
    weights of a depth reading."""
    module = _script("ate_floor_table")
    cameras = [f"{camera}|{frames}=" + str(FIGURES / "ate-floor" / f"{name}-{frames}.csv")
               for camera, name in (("colour, 525 px (registered)", "colour-camera"),
                                    ("the file's 585 px", "depth-camera"))
               for frames in ("1000", "500")]
    weights = [f"{label}|1000=" + str(FIGURES / "ate-floor" / f"colour-camera-1000{tail}.csv")
               for label, tail in (("colour, depth weighed with a 0.02 m baseline",
                                    "-baseline-0.02"),
                                   ("colour, 0.08 m (the edge's)", ""),
                                   ("colour, 0.3 m", "-baseline-0.3"))]
    for args, stages in ((cameras, 4), (weights, 3)):
        module.main(args)
        printed = capsys.readouterr().out
        assert _missing(printed) == []
        assert printed.count("| ground truth, points free |") == stages


def test_the_anchored_floor_table_is_what_its_command_prints(
        capsys: pytest.CaptureFixture[str]) -> None:
    """How close two devices holding the walk's optimum would agree against the truth: the
    stages' revisit, nearby and close errors, both cameras, on the page as printed."""
    module = _script("ate_floor_table")
    module.main(["--anchored",
                 *(f"{camera}|1000=" + str(FIGURES / "ate-floor" / f"anchored-{name}-1000.csv")
                   for camera, name in (("colour, 525 px (registered)", "colour-camera"),
                                        ("the file's 585 px", "depth-camera")))])
    printed = capsys.readouterr().out
    assert _missing(printed) == []
    assert printed.count("| full BA, loops fused") == 2


def test_the_anchored_floor_table_refuses_a_run_from_before_the_anchored_errors() -> None:
    """A CSV the bench wrote before it scored anchored errors has no such columns: refused,
    the file and the columns named, not a table of blanks."""
    module = _script("ate_floor_table")
    with pytest.raises(SystemExit, match=r"colour-camera-1000\.csv: .*revisit_rms_m"):
        module.main(["--anchored", "colour|1000=" + str(FIGURES / "ate-floor" /
                                                        "colour-camera-1000.csv")])


def test_the_ate_floor_table_refuses_a_file_that_is_not_the_bench_s(tmp_path: Path) -> None:
    other = tmp_path / "runs.csv"
    other.write_text("seed,ate_m\n0,0.05\n", encoding="utf-8")
    module = _script("ate_floor_table")
    with pytest.raises(SystemExit, match=r"not a bench\.ate_floor --csv file"):
        module.main([f"colour|1000={other}"])


def test_a_device_variant_table_refuses_a_run_that_dropped_frames(tmp_path: Path) -> None:
    """A run whose device dropped camera frames measured the machine: the table refuses it."""
    folder = tmp_path / "dropped"
    folder.mkdir()
    source = FIGURES / "own-map" / "constrained-own-map"
    (folder / "calibration_frames.csv.gz").write_bytes(
        (source / "calibration_frames.csv.gz").read_bytes())
    with (source / "runs.csv").open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    rows[0]["frames_dropped"] = "12"
    with (folder / "runs.csv").open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with pytest.raises(SystemExit, match="dropped camera frames"):
        _script("device_variants").main([("x", folder)])


#: simulated_restores.py's (paper's edge, archive) CSV pairs under docs/figures/simulated-restores
SIMULATED_RESTORES_TABLES = [(f"{cell}-paper-edge.csv", f"{cell}-archive.csv")
                             for cell in ("v15", "v15-short-loop", "v25")]


@pytest.mark.parametrize(("paper", "archive"), SIMULATED_RESTORES_TABLES,
                         ids=lambda name: name)
def test_each_simulated_restores_table_is_what_its_command_prints(
        paper: str, archive: str, capsys: pytest.CaptureFixture[str]) -> None:
    folder = FIGURES / "simulated-restores"
    _script("simulated_restores").main([str(folder / paper), str(folder / archive)])
    assert _missing(capsys.readouterr().out) == []


def test_a_simulated_restores_table_refuses_other_episodes(tmp_path: Path) -> None:
    """The paired columns compare the same episodes: a file of other seeds is refused."""
    folder = FIGURES / "simulated-restores"
    with (folder / "v15-archive.csv").open(encoding="utf-8") as fh:
        rows = [row for row in csv.DictReader(fh) if row["seed"] != "9"]
    fewer = tmp_path / "fewer.csv"
    with fewer.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with pytest.raises(SystemExit, match="not the same episodes"):
        _script("simulated_restores").main([str(folder / "v15-paper-edge.csv"), str(fewer)])


def test_the_readmes_default_device_table_is_what_its_script_prints() -> None:
    """The README's first screen says which device is the default and why, with the sweep's
    figures: the lines docs/figures/default_device_summary.py prints from the runs.csv files."""
    lines = _script("default_device_summary").table()
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert all(line in readme.splitlines() for line in lines), "\n".join(lines)


def test_the_live_loops_across_table_is_what_its_command_prints() -> None:
    """Loops across devices, live: the ten seeds with and without them, as the page has
    them (the table alone: the command also draws its figure)."""
    module = _script("loops_across_live")
    lines, seeds, _ = module.table(FIGURES / "shared-map" / "loops-across" / "live")
    assert seeds == list(range(10))
    assert _missing("\n".join(lines)) == []


def test_the_live_loops_table_refuses_a_folder_without_both_modes(tmp_path: Path) -> None:
    module = _script("loops_across_live")
    (tmp_path / "own-seed0.csv").write_text("device,cross_device_rms_m\nar1,0.05\n")
    with pytest.raises(SystemExit, match=r"no seed has both own-seedS\.csv and across"):
        module.table(tmp_path)


def test_the_cooldown_per_kind_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A cooldown per loop kind, tried and not kept: the in-process and the live table as
    the page has them."""
    folder = FIGURES / "shared-map" / "loops-across" / "cooldown-per-kind"
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(folder / "live", (("one", "one cooldown for both kinds"),
                                                  ("per-kind", "a cooldown per kind")))
    assert seeds == list(range(10))
    assert _missing("\n".join(lines)) == []
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "in-process" / "one", folder / "in-process" / "per-kind")
    assert _missing("\n".join(printed)) == []
    assert "| two-ends | covered | seeds | 0, 1, 2, 4, 5, 6 | | |" in printed


def test_the_depth_in_pose_table_is_what_its_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Each feature's depth reading in the device's pose refinement, tried on the kitchen's
    two ends: the table with both devices' ATE and lost frames, as the page has it."""
    folder = FIGURES / "shared-map" / "depth-in-pose" / "two-ends"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "pixels", folder / "depth", both_devices=True)
    assert _missing("\n".join(printed)) == []
    assert "| two-ends | covered | seeds | 0, 1, 2, 4, 5, 6, 7 | | |" in printed
    assert any(line.startswith("| two-ends | covered | first device's frames the edge counts "
                               "lost, %") for line in printed)


def test_the_lending_in_view_table_is_what_its_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Lending a keyframe once the borrowing device sees it, against lending it at once: the
    in-process table with the adoptions as the page has it, the kitchen's two ends and the
    corridor's, and the live corridor's, over the seeds the page names."""
    folder = FIGURES / "shared-map" / "lend-in-view"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "eager", folder / "view", adoptions=True)
    assert _missing("\n".join(printed)) == []
    assert "| two-ends | covered | seeds | 0, 1, 2, 4, 5 | | |" in printed
    assert "| corridor-two-ends | covered | seeds | 0, 1, 2, 3, 4 | | |" in printed
    assert any("keyframes the second map adopted" in line for line in printed)
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(folder / "live",
                                 (("eager", "lend_in_view false (lent at once)"),
                                  ("view", "lend_in_view true (the default)")))
    assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == []


def test_the_merge_inlier_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Merges on 100 inliers against 50: the in-process and the live table as the page has
    them, the live one over ten seeds."""
    folder = FIGURES / "shared-map" / "merge-inliers"
    live = _script("loops_across_live")
    lines, seeds, cross = live.table(folder / "live",
                                     (("gate50", "merge on 50 inliers (default)"),
                                      ("gate100", "merge on 100 inliers")))
    assert seeds == list(range(10)) and _missing("\n".join(lines)) == []
    assert all(after < before for before, after in zip(cross["gate50"], cross["gate100"],
                                                        strict=True))
    monkeypatch.syspath_prepend(str(FIGURES))
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "in-process" / "50", folder / "in-process" / "100")
    assert _missing("\n".join(printed)) == []


def test_the_same_frames_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The merge gate scored again on the same frames, and the gate inside the place search:
    the two live tables and the in-process one as the page has them, each with its row over
    the last frames (which older runs' tables lack), over the seeds the page names."""
    folder = FIGURES / "shared-map" / "merge-search"
    live = _script("loops_across_live")
    for modes in ((("gate50", "merge on 50 inliers"), ("post", "merge on 100 inliers (default)")),
                  (("post", "the gate after the search (default)"),
                   ("pass", "the gate in the search"))):
        lines, seeds, _ = live.table(folder / "live", modes)
        assert seeds == list(range(10)) and _missing("\n".join(lines)) == []
        assert any(line.startswith("| cross-device error over the last third") for line in lines)
    monkeypatch.syspath_prepend(str(FIGURES))
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "in-process" / "post100",
                               folder / "in-process" / "pass100")
    assert _missing("\n".join(printed)) == []
    assert any("last 300 frames" in line for line in printed)


def test_the_merge_gate_trials_table_is_what_its_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The merge gate over six trials that start the first device at six places of the walk:
    the table as the page has it, its row over the same frames among it."""
    folder = FIGURES / "shared-map" / "merge-inliers" / "first-starts"
    monkeypatch.syspath_prepend(str(FIGURES))            # its sibling, shared_map_before_after
    trials = _script("shared_map_trials")
    printed = trials.table(folder / "50", folder / "100")
    assert _missing("\n".join(printed)) == []
    assert any("last 300 frames" in line for line in printed)
    assert printed[-1].startswith("| trials (seed/first start/second start) | 0/0/0, 0/10/0")


def test_the_connected_map_tables_are_what_their_command_prints() -> None:
    """The edge's map in pieces with connected_map off and on: each CSV's table as the page
    has it, the corridor's with its mended slots."""
    pieces = _script("map_pieces_table")
    for name in ("corridor-backward-table1.csv", "7scenes-forward-lte.csv",
                 "corridor-backward-table1-edge-map-only.csv"):
        printed = pieces.table(FIGURES / "map-pieces" / name)
        assert _missing("\n".join(printed)) == []
        assert printed[2].startswith("| figure | off (seed by seed) | on | on − off |")


def test_the_live_connected_map_table_is_what_its_command_prints() -> None:
    """connected_map live on the corridor's two ends: the table as the page has it, with the
    map's rows, and no row for a figure no run has (the last thirds share no place)."""
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(FIGURES / "map-pieces" / "live-corridor-one-walk",
                                 (("off", "connected_map false"),
                                  ("on", "connected_map true (the default)")), with_map=True)
    assert seeds == list(range(5))
    assert _missing("\n".join(lines)) == []
    assert any(line.startswith("| ar2 slots with the edge's map in pieces") for line in lines)
    assert not any("nan" in line for line in lines)


def test_the_own_window_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Which keyframes a merged map adjusts: the paper's device and the default device with a
    window of five in process, and the paper's preset live, before and after, as the page
    has them, over the seeds the page names."""
    folder = FIGURES / "shared-map" / "own-window"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    script = _script("shared_map_before_after")
    for device, seeds in (("paper-device", "0, 1, 2, 4, 5, 6, 7, 8"),
                          ("default-device-ba5", "0, 1, 2")):
        printed = script.table(folder / device / "before", folder / device / "after")
        assert _missing("\n".join(printed)) == []
        assert f"| two-ends | covered | seeds | {seeds} | | |" in printed
    live = _script("loops_across_live")
    lines, live_seeds, _ = live.table(folder / "live-paper-preset",
                                      (("before", "the newest ids (kept)"),
                                       ("after", "the map's own newest keyframes")))
    assert live_seeds == [0, 1, 2] and _missing("\n".join(lines)) == []


def test_the_place_walks_tables_are_what_their_command_prints() -> None:
    """Four devices along the corridor: each pair of arms the page compares — copies that go
    back, alone against merged, and the covered view's bounds — as ``place_walks_table.py``
    prints it from the committed CSVs, paired over the seeds the page names; the figure an
    arm has not (the slots after a merge, alone) left out rather than printed as nan."""
    folder = FIGURES / "shared-map" / "place-walks"
    script = _script("place_walks_table")
    for first, second in (("keep", "leave"), ("alone", "keep"), ("covered-off", "keep"),
                          ("keep", "covered-wide"), ("alone", "covered-wide"),
                          ("eight/alone", "eight/shared")):
        printed = script.table(folder / f"{first}.csv", folder / f"{second}.csv")
        assert _missing("\n".join(printed)) == [], (first, second)
        assert ("seeds 0, 1:" if first.startswith("eight") else "seeds 0, 1, 2, 3:") in printed[0]
        assert not any("nan" in line for line in printed)


def test_the_walks_of_their_own_tables_are_what_their_command_prints() -> None:
    """Four devices along the corridor on walks of their own (no image played twice) against
    one walk, each alone against merged, and the covered view's wider bounds on their own
    walks: as ``place_walks_table.py`` prints them from the committed CSVs over seeds 0–3;
    alone on walks of their own there is no cross-device figure (each map in its own first
    camera's frame), left out rather than printed as nan; and the merged arms' rerun, which
    counted the slots planned on a map in pieces the page names."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    script = _script("place_walks_table")
    for first, second in (("whole", "own"), ("own-alone", "own"), ("whole-alone", "whole"),
                          ("own", "own-wide")):
        printed = script.table(folder / f"{first}.csv", folder / f"{second}.csv")
        assert _missing("\n".join(printed)) == [], (first, second)
        assert "seeds 0, 1, 2, 3:" in printed[0]
        assert not any("nan" in line for line in printed)
    alone_rows = script.table(folder / "own-alone.csv", folder / "own.csv")
    assert not any("cross-device" in line for line in alone_rows)
    # the merged arms run again with the slots on a map in pieces counted: the same walks to
    # the digit but the timings, the pieces the page names (one device a seed, none on one walk)
    from bench.place_walks import SAME_WALK

    for arm, pieces in (("own", ["4;0;0;0", "0;0;0;0", "0;0;0;38", "0;0;23;0"]),
                        ("whole", ["0;0;0;0"] * 4)):
        first, rerun = (script.runs(f) for f in (folder / f"{arm}.csv",
                                                 folder / "rerun" / f"{arm}.csv"))
        assert [rerun[s]["device_pieces_slots"] for s in range(4)] == pieces
        for seed in range(4):
            assert all(first[seed][k] == rerun[seed][k] for k in SAME_WALK), (arm, seed)


def test_the_covered_view_bounds_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The covered view's bounds judged on the 7-Scenes walk: the in-process uplink table at
    the old bounds, the new and the wider ones looked at afterwards (seed 3, which drew seed
    2's uplink, left out), and the live table of the old and the new, as the page has them."""
    folder = FIGURES / "shared-map" / "covered-bounds"
    monkeypatch.syspath_prepend(str(FIGURES))
    uplink = _script("shared_uplink_table")
    for bounds in ("narrow", "wide", "wider"):
        rows = [row.strip() for row in uplink.table(folder / bounds, "mapped")]
        assert _on_a_page(rows), bounds
        assert len(rows) == 4 and all(row.endswith("| 0, 1, 2, 4, 5 |") for row in rows)
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(folder / "live",
                                 (("narrow", "covered_m 0.1, covered_deg 10 (the default "
                                   "before)"),
                                  ("wide", "covered_m 0.3, covered_deg 20")), with_map=True)
    assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == []


def test_the_covered_bounds_curve_table_is_what_its_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The covered view's bounds from 0.10 m to 0.50 m on the corridor, beside the devices
    alone: the table as the page has it, every bound over the four seeds, and the figure a
    bound's runs lack printed as a dash, not a number."""
    folder = FIGURES / "shared-map" / "place-walks" / "curve"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, place_walks_table
    script = _script("covered_bounds_curve")
    points = script.curve(folder / "alone.csv",
                          [folder / f"bounds-{m}.csv" for m in ("0.1", "0.2", "0.3", "0.5")])
    printed = script.table(points)
    assert _missing("\n".join(printed)) == []
    assert [label for label, _, _ in points] == ["alone", "0.1 m, 10°", "0.2 m, 15°",
                                                 "0.3 m, 20°", "0.5 m, 30°"]
    assert all(seeds == [0, 1, 2, 3] for _, seeds, _ in points)


def test_a_side_by_side_run_that_walked_another_walk_shows_the_walks_figures(
        tmp_path: Path) -> None:
    """Where the two trees walked different walks (a change that alters what the edge
    decides), the beside-table names the figures that differ and shows the walk's own figures
    side by side, in the units the pages use: the timings alone would hide a worse map."""
    source = FIGURES / "shared-map" / "place-walks" / "sorted-copy-rows" / "seed-0.csv"
    with source.open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    for row in rows:
        if row["tree"] == "current":
            row["loops"] = str(int(row["loops"]) + 2)
            row["cross_rms_m"] = str(float(row["cross_rms_m"]) + 0.01)
    changed = tmp_path / "seed-0.csv"
    with changed.open("w", encoding="utf-8", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    printed = _script("place_walks_beside_table").table([changed])
    assert "Figures that differ between the trees: cross_rms_m, loops." in printed
    loops = next(line for line in printed if line.startswith("| loops closed |"))
    base = next(r for r in rows if r["tree"] == "baseline")
    assert f"| {int(base['loops'])} | {int(base['loops']) + 2} | +2.00" in loops
    cross = next(line for line in printed if line.startswith("| cross-device revisit"))
    assert f"{100 * float(base['cross_rms_m']):.2f}" in cross and "+1.00" in cross


def test_the_process_vocabulary_table_is_what_its_command_prints() -> None:
    """Eight devices alone with one vocabulary a process against one a device: the loop
    closing page holds the table ``place_walks_beside_table.py`` prints from the committed
    runs, line for line, and the walk's figures the page reads as equal are so."""
    folder = FIGURES / "shared-map" / "place-walks" / "process-vocabulary"
    rows = []
    for path in sorted(folder.glob("seed-*.csv")):
        with path.open(encoding="utf-8") as fh:
            rows += list(csv.DictReader(fh))
    printed = _script("place_walks_beside_table").table(sorted(folder.glob("seed-*.csv")))
    page = (REPO / "docs" / "results" / "loop-closing.md").read_text(encoding="utf-8")
    lines = page.splitlines()
    assert any(lines[i:i + len(printed)] == printed for i in range(len(lines)))
    for figure in ("loops", "uploads", "device_ate_m"):
        assert len({(r["seed"], r[figure]) for r in rows}) == 2, figure   # one value a seed


@pytest.mark.parametrize("runs", ["edge-cuts", "sorted-copy-rows", "point-order-and-place-words"])
def test_the_shared_place_work_table_is_what_its_command_prints(runs: str) -> None:
    """A shared place's edge work in two trees: the benchmark page holds the table
    ``place_walks_beside_table.py`` prints from the committed side-by-side runs, line for
    line, and both trees walked the same walk (every figure but the timings equal)."""
    folder = FIGURES / "shared-map" / "place-walks" / runs
    printed = _script("place_walks_beside_table").table(sorted(folder.glob("seed-*.csv")))
    page = (REPO / "docs" / "benchmarks" / "shared-place.md").read_text(encoding="utf-8")
    lines = page.splitlines()
    assert any(lines[i:i + len(printed)] == printed for i in range(len(lines)))
    assert printed[-1] == "The same walk in both trees: every other figure equal."
    assert "seeds 0, 1:" in printed[0]
    # the script's figures of one walk are the bench's (it runs without bench on its path)
    from bench.place_walks import SAME_WALK
    assert _script("place_walks_beside_table").SAME_WALK == SAME_WALK


@pytest.mark.parametrize("runs", ["votes-to-solve", "look-screen"])
def test_the_looks_tables_are_what_their_command_prints(runs: str) -> None:
    """Six devices over three places, the place search's votes gate and then the looks'
    screen, each against the tree before it: the shared-map page holds each table
    ``place_walks_beside_table.py --looks`` prints from the committed runs, line for line,
    and every seed walked one walk in both trees (the page reads the looks' time on the same
    looks)."""
    folder = FIGURES / "shared-map" / "place-walks" / runs
    runs_csv = sorted(folder.glob("seed-*.csv"))
    printed = _script("place_walks_beside_table").table(runs_csv, looks=True)
    page = (REPO / "docs" / "results" / "shared-map.md").read_text(encoding="utf-8")
    lines = page.splitlines()
    assert len(runs_csv) == 4 and any(lines[i:i + len(printed)] == printed
                                  for i in range(len(lines)))
    assert printed[-1] == "The same walk in both trees: every other figure equal."


@pytest.mark.parametrize("runs", ["keyframe-database/six", "keyframe-database/nine",
                                  "keyframe-rows/nine"])
def test_the_keyframe_database_tables_are_what_their_command_prints(runs: str) -> None:
    """Six and nine devices over three places, the looks sent where the keyframe database
    ranks first against the looks in turn, and nine with four keyframes a row against one:
    the shared-map page holds each table ``place_walks_beside_table.py --looks --merges``
    prints from the committed runs, line for line, with no false merge in either tree."""
    folder = FIGURES / "shared-map" / "place-walks" / runs
    runs_csv = sorted(folder.glob("seed-*.csv"))
    printed = _script("place_walks_beside_table").table(runs_csv, looks=True, merges=True)
    page = (REPO / "docs" / "results" / "shared-map.md").read_text(encoding="utf-8")
    lines = page.splitlines()
    assert len(runs_csv) == 2 and any(lines[i:i + len(printed)] == printed
                                      for i in range(len(lines)))
    assert "False merges: 0 in the baseline, 0 in this tree; devices merged in one tree " \
        "only: 0." in printed


def test_the_keyframe_databases_places_apart_are_what_the_page_says() -> None:
    """The words tell places apart as the shared-map page says: at 1024 words, 449 of the
    450 frames (three places, three vocabularies) scored their own place first."""
    path = FIGURES / "shared-map" / "keyframe-database" / "places-apart.csv"
    with path.open(encoding="utf-8") as fh:
        rows = [row for row in csv.DictReader(fh) if row["words"] == "1024"]
    won = sum(int(row["own_first"]) for row in rows)
    asked = sum(int(row["queries"]) for row in rows)
    page = (REPO / "docs" / "results" / "shared-map.md").read_text(encoding="utf-8")
    assert (won, asked) == (449, 450) and f"| 1024 | {won} of {asked} |" in page


def test_the_keyframe_databases_rows_table_is_what_its_csv_says() -> None:
    """The table of keyframes a row on the shared-map page sums its CSV: for each count, the
    frames whose own place scored first and those with another place within the candidates'
    share, over the three vocabularies (and four a row told the places apart as one did)."""
    path = FIGURES / "shared-map" / "keyframe-database" / "places-apart-rows.csv"
    with path.open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    page = (REPO / "docs" / "results" / "shared-map.md").read_text(encoding="utf-8")
    won_by_count = {}
    for count in sorted({int(row["keyframes_a_row"]) for row in rows}):
        mine = [row for row in rows if int(row["keyframes_a_row"]) == count]
        won = sum(int(row["own_first"]) for row in mine)
        asked = sum(int(row["queries"]) for row in mine)
        near = sum(int(row["another_candidate"]) for row in mine)
        filed = 3 * -(-50 // count)     # three places' rows: a keyframe every 20 of 1000 frames
        assert f"| {count} | {filed} | {won} of {asked} |" in page, count
        assert any(line.startswith(f"| {count} | {filed} |") and line.endswith(f"| {near} |")
                   for line in page.splitlines()), count
        won_by_count[count] = won
    assert won_by_count[4] == won_by_count[1] == 449


def test_the_own_coverage_tables_are_what_their_command_prints() -> None:
    """A device's own keyframes of an earlier visit covering its views, against the paper's
    uploads, by pose alone and with the heading gate: the two places' table and the held-out
    room's (its first device alone: the second repeats the next seed's first), six seeds
    each, as the page has them."""
    folder = FIGURES / "shared-map" / "own-coverage"
    script = _script("own_coverage_table")
    for version in ("own-10", "own-10-heading"):         # by pose alone, the heading gate
        two = script.table(folder / "two-places-paper.csv",
                           folder / f"two-places-{version}.csv")
        room = script.table(folder / "room-paper.csv", folder / f"room-{version}.csv",
                            ("synthetic room, forward and back",))
        for printed in (two, room):
            assert _missing("\n".join(printed)) == [], version
            assert printed[-1].endswith("| seeds | 0, 1, 2, 3, 4, 5 | | |")
        assert sum(" | keyframes uploaded | " in row for row in two) == 2
        assert sum(" | keyframes uploaded | " in row for row in room) == 1



def test_the_covered_margin_tables_are_what_their_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A covered frame left out only where the map serves it with a margin: the 7-Scenes
    walk's uplink table at 50 points (seed 3, which drew seed 2's uplink, left out), the
    paired table of 50 points against the tracking floor with both devices' lost frames, and
    the two places walked forward and back with the device's own keyframes covering at 50
    points, against the paper's uploads run beside them, as the page has them."""
    folder = FIGURES / "shared-map" / "covered-margin"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    uplink = _script("shared_uplink_table")
    rows = [row.strip() for row in uplink.table(folder / "at-50", "mapped")]
    assert _on_a_page(rows)
    assert len(rows) == 4 and all(row.endswith("| 0, 1, 2, 4, 5 |") for row in rows)
    in_process = _script("shared_map_before_after")
    printed = in_process.table(folder / "at-15", folder / "at-50", both_devices=True)
    assert _missing("\n".join(printed)) == []
    assert "| mapped | covered | seeds | 0, 1, 2, 4, 5 | | |" in printed
    own = FIGURES / "shared-map" / "own-coverage"
    two = _script("own_coverage_table").table(own / "two-places-paper-beside-margin-50.csv",
                                              own / "two-places-own-10-margin-50.csv")
    assert _missing("\n".join(two)) == []
    assert two[-1].endswith("| seeds | 0, 1, 2, 3, 4, 5 | | |")
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(folder / "live",
                                 (("beside-15", "covered_min_points 15 (the default)"),
                                  ("beside-50", "covered_min_points 50")), with_map=True)
    assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == []


def test_the_margin_as_the_default_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The covered view's margin of 50 points made the default: the 7-Scenes walk's uplink
    table at 50 and the held-out corridor's, 50 against the floor seed by seed, and live
    against the floor and against each device alone, as the page has them; the rows at 15
    and 30 points the page quotes say what it says."""
    folder = FIGURES / "shared-map" / "covered-margin" / "default-50"
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    uplink = _script("shared_uplink_table")
    for place in ("at-50", "corridor-at-50"):
        rows = [row.strip() for row in uplink.table(folder / place, "mapped")]
        assert _on_a_page(rows), place
        assert len(rows) == 4 and all(row.endswith("| 0, 1, 2, 4, 5 |") for row in rows)
    for margin, saved, lost in (("at-15", "61.7 ± 4.4 %", "+5.6 [+2.7, +8.5]"),
                                ("at-30", "50.6 ± 2.9 %", "+3.1 [+1.8, +4.5]")):
        (row,) = [r for r in uplink.table(folder / margin, "mapped")
                  if r.startswith("| mapped | second | covered |")]
        assert f"| {saved} |" in row and f"| {lost} |" in row, (margin, row)
    printed = _script("shared_map_before_after").table(folder / "at-15", folder / "at-50",
                                                       both_devices=True)
    assert _missing("\n".join(printed)) == []
    live = _script("loops_across_live")
    now = ("m50", "covered_min_points 50 (the default now)")
    for before in (("m15", "covered_min_points 15 (the default before)"),
                   ("alone", "each device alone (merge_maps off)")):
        lines, seeds, _ = live.table(folder / "live", (before, now), with_map=True)
        assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == [], before


def test_the_words_learned_beside_the_looks_table_is_what_its_command_prints() -> None:
    """Live, the keyframe database's words learned by the first look against beside the
    looks: the second device's merge and uploads over three seeds, as the page has them."""
    live = _script("loops_across_live")
    lines, seeds, _ = live.table(FIGURES / "shared-map" / "words-beside" / "live",
                                 (("in-look", "words learned by the first look (before)"),
                                  ("beside", "words learned beside the looks")), with_map=True)
    assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == []
    assert any(line.startswith("| ar2 frames uploaded | 30, 33, 34 | 15, 19, 13 |")
               for line in lines)
    against, seeds, _ = live.table(FIGURES / "shared-map" / "words-beside" / "live",
                                   (("alone", "each device alone (merge_maps off)"),
                                    ("beside", "merged, the default covers")), with_map=True)
    assert seeds == [0, 1, 2] and _missing("\n".join(against)) == []


def test_the_slot_threads_shares_at_fifty_devices_are_what_their_command_prints() -> None:
    """py-spy's stacks of the fifty-device edge and its emulated devices: the shares the page
    prints are what the committed recordings give, and the log lines' share fell."""
    shares = _script("stack_shares")
    stacks = FIGURES / "fleet" / "fifty" / "stacks"
    edge = shares.table([("rclpy's logger", stacks / "edge-rclpy-logger.txt.gz"),
                         ("the site logger", stacks / "edge-site-logger.txt.gz")])
    assert _missing("\n".join(edge)) == []
    assert "| `RcutilsLogger.log` | 7.1 % | 0.1 % |" in edge
    devices = shares.table(
        [("the emulated devices", stacks / "emulated-devices.txt.gz")],
        functions=("RosSession.spin_once", "Executor._wait_for_ready_callbacks",
                   "EventHandler.add_to_wait_set", "EmulatedDevice.tick",
                   "Recording.of_place", "Publisher.publish"))
    assert _missing("\n".join(devices)) == []


def test_the_emulators_executor_table_is_what_its_command_prints() -> None:
    """Fifty emulated devices on either executor, one and two edges, two rounds."""
    fleet = _script("fleet_tables")
    folder = FIGURES / "fleet" / "fifty" / "emulator-executor"
    lines = fleet.emulator_table([folder / "round-1.csv", folder / "round-2.csv"])
    assert _missing("\n".join(lines)) == []
    assert lines[-1].startswith("| `EventsExecutor` | 2 | 54.1 / 48.4 % |")


def test_the_keeping_up_edges_shares_are_what_their_command_prints() -> None:
    """py-spy's stacks of an edge serving 24 devices: its slot thread and its loop worker."""
    shares = _script("stack_shares")
    stacks = FIGURES / "fleet" / "fifty" / "stacks" / "edge-24-devices.txt.gz"
    slot = shares.table([("24 devices, one edge", stacks)], functions=(
        "CheckedSubscription._on_data", "DeviceLink._on_keyframe", "LocalMapping.integrate",
        "LocalMapping._alike_finder", "LocalMapping._flush", "DeviceLink._on_summaries",
        "EdgeMapperCore.plan", "DeviceLink.finish_due"))
    worker = shares.table([("the loop worker", stacks)], thread="loop-closer_0", functions=(
        "detect_loop", "KeyFrameArchive.recognise", "_solve", "SharedWorker.wait_for_slots"))
    assert _missing("\n".join(slot)) == [] and _missing("\n".join(worker)) == []


def test_the_view_lent_once_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A view lent once: eight devices along the corridor with and without it (four seeds at
    0.30 m, two at 0.10 m), and the 7-Scenes pair at 0.30 m and at 0.10 m beside alone and
    beside lending every keyframe, as the page has them."""
    corridor = FIGURES / "shared-map" / "place-walks" / "views-once"
    script = _script("place_walks_table")
    for arm, seeds in (("covered-bounds", "0, 1, 2, 3"), ("0.1m", "0, 1")):
        printed = script.table(corridor / "off.csv", corridor / f"{arm}.csv", last_device=True)
        assert _missing("\n".join(printed)) == [] and f"seeds {seeds}:" in printed[0], arm
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    uplink = _script("shared_uplink_table")
    pair = FIGURES / "shared-map" / "views-once"
    for bounds in ("mapped-0.3m", "mapped-0.1m"):
        rows = [row.strip() for row in uplink.table(pair / bounds, "mapped")]
        assert _on_a_page(rows), bounds
        assert len(rows) == 4 and all(row.endswith("| 0, 1, 2, 4, 5 |") for row in rows)
    in_process = _script("shared_map_before_after")
    lines = in_process.table(FIGURES / "shared-map" / "covered-margin" / "default-50" / "at-50",
                             pair / "mapped-0.1m", both_devices=True)
    assert _missing("\n".join(lines)) == []


def test_the_copy_points_held_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A copy's points held already: the 7-Scenes pair at a share of 0.3 against the default,
    eight devices along the corridor at 0.9, a view lent once with the devices walking both
    ways, and the view overlap of the sample and the room, as the page has them."""
    held = FIGURES / "shared-map" / "points-held"
    corridor = _script("place_walks_table").table(held / "place-walks" / "off.csv",
                                                  held / "place-walks" / "share-0.9.csv",
                                                  last_device=True)
    assert _missing("\n".join(corridor)) == [] and "seeds 0, 1:" in corridor[0]
    both_ways = FIGURES / "shared-map" / "place-walks" / "views-once" / "both-ways"
    walks = _script("place_walks_table").table(both_ways / "off.csv", both_ways / "0.3m.csv",
                                               last_device=True)
    assert _missing("\n".join(walks)) == [] and "forward,backward" in walks[0]
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    pair = _script("shared_map_before_after").table(held / "mapped-default",
                                                    held / "mapped-share-0.3",
                                                    adoptions=True, both_devices=True)
    assert _missing("\n".join(pair)) == []
    from bench.view_overlap import read_pairs, table
    for name in ("7scenes", "synthetic-room"):
        printed = table(read_pairs(FIGURES / "shared-map" / "view-overlap" / f"{name}.csv"))
        assert _on_a_page(printed), name


def test_the_live_runs_that_never_show_one_image_are_what_their_commands_print() -> None:
    """Two devices in a mapped place, live, every second frame each (no image shared):
    against every frame in one place and against each device alone; and from the walk's two
    ends, every second frame against every frame: as the page has them."""
    live = _script("loops_across_live")
    folder = FIGURES / "shared-map" / "interleaved" / "live"
    for before in (("shared1", "in one place, every frame (the images shared)"),
                   ("alone2", "each device alone, every second frame (merge_maps off)")):
        lines, seeds, _ = live.table(
            folder, (before, ("shared2", "in one place, every second frame (no image shared)")),
            with_map=True)
        assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == [], before
    lines, seeds, _ = live.table(
        FIGURES / "shared-map" / "interleaved" / "live-two-ends",
        (("ends1", "every frame (the images shared)"),
         ("ends2", "every second frame (no image shared)")), with_map=True)
    assert seeds == [0, 1, 2] and _missing("\n".join(lines)) == []


def test_the_cross_device_split_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The cross-device error split in two, seed by seed, and the merge's alignment from the
    mean of its detections, from the one with the most inliers, from the confirming one
    placed on the other map's points and from one fit to all the detections' depth matches
    against the confirming one, as the page has them."""
    rigid = FIGURES / "shared-map" / "rigid-part"
    split = _script("cross_device_split_table").table(
        [("two-ends", rigid / "two-ends.csv"),
         ("two-ends, interleaved", rigid / "interleaved-two-ends.csv"),
         ("mapped", rigid / "mapped.csv"),
         ("mapped, interleaved", rigid / "interleaved-mapped.csv")])
    assert _missing("\n".join(split)) == []
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    before_after = _script("shared_map_before_after")
    alignments = rigid / "merge-alignment"
    for tried in ("mean", "most-inliers"):
        printed = before_after.table(alignments / "last", alignments / tried)
        assert _missing("\n".join(printed)) == [], tried
    for before, tried in (("interleaved-confirming", "on-place-points"),
                          ("interleaved-confirming-12", "joint")):
        printed = before_after.table(alignments / before, alignments / tried)
        assert _missing("\n".join(printed)) == [], tried
    on_points = _script("cross_device_split_table").table(
        [("two-ends, on the place's points",
          alignments / "on-place-points" / "uplink-two-ends-covered.csv")])
    assert _missing("\n".join(on_points)) == []
    uplink = _script("shared_uplink_table")
    rows = [row.strip() for scenario in ("mapped", "two-ends")
            for row in uplink.table(FIGURES / "shared-map" / "interleaved", scenario)]
    assert _on_a_page(rows) and len(rows) == 8


def test_the_left_piece_tables_are_what_their_command_prints() -> None:
    """Four devices on walks of their own with a split map kept (the evening's rerun, and the
    code before beside this one on seeds 4–7) against the piece the camera left dropped: the
    tables as ``place_walks_table.py --names`` prints them, every seed's pieces as the page
    has them, and the seeds whose maps never split the same walk to the digit."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    script = _script("place_walks_table")
    names = ("a split map kept", "the left piece dropped")
    for first, second, seeds in ((folder / "rerun" / "own.csv",
                                  folder / "left-piece" / "dropped.csv", "0, 1, 2, 3"),
                                 (folder / "left-piece" / "kept-4-7.csv",
                                  folder / "left-piece" / "dropped-4-7.csv", "4, 5, 6, 7")):
        printed = script.table(first, second, names=names)
        assert _missing("\n".join(printed)) == [], (first, second)
        assert f"seeds {seeds}:" in printed[0] and "| a split map kept (seed by seed) |" in \
            printed[2]
    dropped = script.runs(folder / "left-piece" / "dropped.csv")
    assert [dropped[s]["device_pieces_slots"] for s in range(4)] == \
        ["1;0;0;0", "0;0;0;0", "0;0;0;1", "0;0;2;0"]
    from bench.place_walks import SAME_WALK

    kept = script.runs(folder / "rerun" / "own.csv")
    assert all(kept[1][k] == dropped[1][k] for k in SAME_WALK)        # seed 1 never split
    before, after = (script.runs(folder / "left-piece" / f"{arm}-4-7.csv")
                     for arm in ("kept", "dropped"))
    for seed in range(4, 8):
        assert after[seed]["device_pieces_slots"] == "0;0;0;0"
        assert all(before[seed][k] == after[seed][k] for k in SAME_WALK), seed


def test_the_wider_covers_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Covers widened to 0.50 m and 45° on walks of their own (the training seeds against the
    default and alone, the held-out seeds, the fraction carried) and on the held-out 7-Scenes
    pair: each table as the page has it, and the default's 7-Scenes runs the very walks of
    the interleaved runs before them."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    script = _script("place_walks_table")
    for first, second, names in (
            ("left-piece/dropped.csv", "bounds/wide-0.5-45.csv", None),
            ("own-alone.csv", "bounds/wide-0.5-45.csv", None),
            ("left-piece/dropped-4-7.csv", "bounds/wide-0.5-45-4-7.csv", None),
            ("bounds/wide-0.5-45.csv", "bounds/wide-carried.csv",
             ("each slot rounded up (the code)", "a fraction carried (tried)"))):
        printed = script.table(folder / first, folder / second, names=names)
        assert _missing("\n".join(printed)) == [], (first, second)
    wide = script.runs(folder / "bounds" / "wide-0.5-45.csv")
    assert {float(run["covered_m"]) for run in wide.values()} == {0.5}
    monkeypatch.syspath_prepend(str(FIGURES))            # its sibling, shared_uplink_table
    choice = FIGURES / "shared-map" / "covered-bounds" / "own-walks-choice"
    for after in ("wide", "carried-default"):
        printed = _script("shared_map_before_after").table(choice / "default", choice / after,
                                                             both_devices=True)
        assert _missing("\n".join(printed)) == [], after
    for scenario in ("mapped", "two-ends"):
        with (FIGURES / "shared-map" / "interleaved" / f"uplink-{scenario}-covered.csv").open() \
                as before, (choice / "default" / f"uplink-{scenario}-covered.csv").open() as now:
            old, new = list(csv.DictReader(before)), list(csv.DictReader(now))
        assert [r["second_uploads"] for r in old] == [r["second_uploads"] for r in new]


def test_the_cover_by_points_tables_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The cover judged by the points a frame tracks on, on walks of their own (the training
    seeds against the pose test and alone, the bar of 100 points, the held-out seeds against
    the pose test and alone, and the pose test against alone there) and on
    the held-out 7-Scenes pair: each table as the page has it, and the committed code's run
    of seed 0 the very walk of the tried patch's."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    script = _script("place_walks_table")
    for first, second, names in (
            ("left-piece/dropped.csv", "points/by-points-50.csv", ("pose (the default)",
                                                                  "by points")),
            ("own-alone.csv", "points/by-points-50.csv", ("alone", "by points")),
            ("points/by-points-50.csv", "points/by-points-100.csv",
             ("by points at 50", "by points at 100")),
            ("left-piece/dropped-4-7.csv", "points/by-points-50-4-7.csv",
             ("pose (the default)", "by points")),
            ("own-alone-4-7.csv", "points/by-points-50-4-7.csv", ("alone", "by points")),
            ("own-alone-4-7.csv", "left-piece/dropped-4-7.csv", ("alone", "pose (the default)")),
            ("points/by-points-50.csv", "points/points-wide.csv",
             ("by points", "by points and 0.50 m / 45°"))):
        printed = script.table(folder / first, folder / second, names=names)
        assert _missing("\n".join(printed)) == [], (first, second)
    tried = script.runs(folder / "points" / "by-points-50.csv")
    committed = script.runs(folder / "points" / "committed-seed0.csv")
    assert {run["covered_by_points"] for run in committed.values()} == {"1"}
    for column in ("device_uploads", "lost_share", "cross_rms_m", "copies_end", "loops"):
        assert [run[column] for run in committed.values()] == \
            [run[column] for seed, run in tried.items() if seed in committed], column
    monkeypatch.syspath_prepend(str(FIGURES))            # its sibling, shared_uplink_table
    choice = FIGURES / "shared-map" / "covered-bounds" / "own-walks-choice"
    printed = _script("shared_map_before_after").table(choice / "default", choice / "by-points",
                                                         both_devices=True)
    assert _missing("\n".join(printed)) == []


def test_where_the_cover_by_points_loses_frames_is_what_its_command_prints() -> None:
    """The held-out walks' frames, alone and with the cover by points, as the frames script
    prints them; and the committed code's runs are the walks of the tables before them (the
    same uploads, lost shares and loops, seed by seed)."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks" / "points"
    lost = folder / "where-lost"
    runs = [(f"{name}, seed {seed}", lost / f"{file}-{seed}.frames.csv.gz")
            for seed in (4, 5) for name, file in (("alone", "alone"), ("by points", "by-points"))]
    printed = _script("place_walks_frames").tables(runs)
    assert _missing("\n".join(printed)) == []
    table = _script("place_walks_table")
    for committed, earlier in (("by-points-4-5.csv", folder / "by-points-50-4-7.csv"),
                               ("alone-4-5.csv", folder.parent / "own-alone-4-7.csv")):
        now, before = table.runs(lost / committed), table.runs(earlier)
        assert sorted(now) == [4, 5]
        for column in ("device_uploads", "lost_share", "loops", "copies_end"):
            assert [now[s][column] for s in (4, 5)] == [before[s][column] for s in (4, 5)]


def test_the_devices_search_of_the_map_before_and_after_is_what_its_commands_print() -> None:
    """The held-out walks' frames with the cover by points, the device's search of its map
    before and after the edge's points and its own were given half the searches each, as the
    frames script prints them; the paired tables of every walk before and after; and the
    runs before repeat the walks of the section before them (the search recorded, nothing
    else changed)."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    search = folder / "candidate-search"
    runs = [(f"{tree}, seed {seed}", search / tree / f"by-points-{seed}.frames.csv.gz")
            for seed in (4, 5) for tree in ("before", "after")]
    printed = _script("place_walks_frames").tables(runs)
    assert _missing("\n".join(printed)) == []
    table = _script("place_walks_table")
    names = ("ranked by sighting", "half each")
    for walks in ("alone", "default", "by-points"):
        printed = table.table(search / "before" / f"{walks}.csv", search / "after" / f"{walks}.csv",
                              names=names)
        assert _missing("\n".join(printed)) == [], walks
    printed = table.table(search / "before" / "by-points.csv",
                          search / "tried" / "edge-first-by-points-4-5.csv",
                          names=("ranked by sighting", "the edge's first"))
    assert _missing("\n".join(printed)) == []
    now = table.runs(search / "before" / "by-points.csv")
    earlier = table.runs(folder / "points" / "where-lost" / "by-points-4-5.csv")
    for column in ("device_uploads", "lost_share", "loops", "copies_end", "cross_rms_m"):
        assert [now[s][column] for s in (4, 5)] == [earlier[s][column] for s in (4, 5)]


def test_the_copies_seen_from_afar_and_the_view_angle_tried_are_what_their_commands_print(
        ) -> None:
    """The held-out walks' frames with the cover by points and the 7-Scenes pair's, the
    edge's points in view seen from over 60° off, as the frames script prints them; the
    paired tables of every walk with
    every point in view and with 60°; and the frames' runs repeat the walks they were
    compared with (the directions recorded, nothing searched differently)."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks"
    seen = folder / "view-angle" / "seen-from-afar"
    runs = [(f"seed {seed}", seen / f"by-points-{seed}.frames.csv.gz") for seed in (4, 5)]
    printed = _script("place_walks_frames").tables(runs)
    assert any(line.startswith("| seed 4 | lost by the edge | 649 |") for line in printed)
    assert _missing("\n".join(printed[-6:])) == []
    pair = [("7-Scenes pair, by points", seen / "seven-scenes-by-points.frames.csv.gz")]
    assert _missing("\n".join(_script("place_walks_frames").tables(pair)[-4:])) == []
    table = _script("place_walks_table")
    for walks in ("alone", "default", "by-points"):
        printed = table.table(folder / "candidate-search" / "after" / f"{walks}.csv",
                              folder / "view-angle" / "gate-60" / f"{walks}.csv",
                              names=("every point in view", "60°"))
        assert _missing("\n".join(printed)) == [], walks
    for seed, (_, path) in zip((4, 5), runs, strict=True):
        before = folder / "candidate-search" / "after" / f"by-points-{seed}.frames.csv.gz"
        with gzip.open(before, "rt", encoding="utf-8") as old, \
                gzip.open(path, "rt", encoding="utf-8") as new:
            for was, now in zip(csv.DictReader(old), csv.DictReader(new), strict=True):
                assert was == {key: now[key] for key in was}, seed


def test_the_cover_by_points_gated_by_viewing_direction_is_what_its_commands_print() -> None:
    """The walks of their own with the cover by points counting every shared point and only
    those seen from within 60° of the lenders' direction, and each against the devices alone,
    as the table script prints them; the 7-Scenes pair with the gate repeats the pair without
    it in every count (one walk: no point seen from afar)."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks" / "view-angle"
    gate = folder / "cover-gate-60"
    table = _script("place_walks_table")
    held_out = (4, 5, 6, 7, 8, 9)            # the cover by points' bar was set on seeds 0-3
    for before, after, names, seeds in (("by-points", "gated", ("by points", "60°"), None),
                                        ("alone", "by-points", ("alone", "by points"), held_out),
                                        ("alone", "gated", ("alone", "60°"), None)):
        printed = table.table(gate / f"{before}.csv", gate / f"{after}.csv", names=names,
                              only_seeds=seeds)
        assert _missing("\n".join(printed)) == [], (before, after)
    with pytest.raises(SystemExit, match=r"seeds \[6\] are not in both"):
        table.table(gate / "alone.csv", gate / "gated.csv", only_seeds=(4, 6))
    with (folder / "seen-from-afar" / "seven-scenes-by-points.csv").open(encoding="utf-8") as fh:
        plain = next(csv.DictReader(fh))
    with (gate / "seven-scenes-gated.csv").open(encoding="utf-8") as fh:
        gated = next(csv.DictReader(fh))
    for column in ("uploads", "lost_share", "map_lost_share", "copies_end", "cross_rms_m",
                   "ate_m_mean", "loops", "device_uploads"):
        assert plain[column] == gated[column], column


def test_devices_with_cameras_of_their_own_are_what_their_commands_print() -> None:
    """Four devices of two camera models on walks of their own: each keyframe read with the
    map's device's camera (before) and with its own (after), after against the devices alone
    and against one camera model, as the table script prints them; with one camera model the
    change repeats the walk to the digit."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks" / "cameras"
    table = _script("place_walks_table")
    for first, second, names in (("before", "after", ("before", "after")),
                                 ("alone", "after", ("alone", "after")),
                                 ("one-camera", "after", ("one camera", "two"))):
        printed = table.table(folder / f"{first}.csv", folder / f"{second}.csv", names=names)
        assert _missing("\n".join(printed)) == [], (first, second)
    from bench.place_walks import SAME_WALK

    with (folder / "one-camera-before.csv").open(encoding="utf-8") as fh:
        before = next(csv.DictReader(fh))
    with (folder / "one-camera.csv").open(encoding="utf-8") as fh:
        after = next(row for row in csv.DictReader(fh) if row["seed"] == before["seed"])
    for column in SAME_WALK:
        assert before[column] == after[column], column


def test_devices_with_cameras_of_their_own_live_are_what_their_command_prints() -> None:
    """Two devices of two camera models live, each keyframe read with the map's device's
    camera and with its own, on the two walks whose cameras dropped no frame, as the live
    table script prints them."""
    folder = FIGURES / "shared-map" / "place-walks" / "own-walks" / "cameras" / "live"
    live = _script("loops_across_live")
    modes = (("before", "each keyframe read with the map's camera"),
             ("after", "each with its own"))
    for runs, seed in (("1200-frames", 0), ("2700-frames-paced", 1)):
        lines, seeds, _ = live.table(folder / runs, modes)
        assert seeds == [seed]
        assert _missing("\n".join(lines)) == [], runs


def test_one_map_a_place_against_lent_copies_is_what_its_command_prints(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The second device's map joined into the first's against lent copies, from the walk's
    two ends at once and coming to a mapped place (with the device alone), as the table
    script prints them."""
    monkeypatch.syspath_prepend(str(FIGURES))           # its sibling, shared_uplink_table
    folder = FIGURES / "shared-map" / "joined"
    table = _script("joined_place_table")
    printed = table.table(folder / "two-ends" / "lend.csv", folder / "two-ends" / "join.csv")
    assert _missing("\n".join(printed)) == []
    printed = table.table(folder / "later" / "lend.csv", folder / "later" / "join.csv",
                          folder / "later" / "alone.csv")
    assert _missing("\n".join(printed)) == []
    assert printed[0] == "seeds 0, 1, 2, 4, 5, 6, 7"
    # the local adjustment on: the place's once, and a window shared among the walks tried
    window = folder / "ba-window-6"
    for first, second in (("lend", "join"), ("join", "join-window-each-walk")):
        printed = table.table(window / f"{first}.csv", window / f"{second}.csv")
        assert _missing("\n".join(printed)) == [], (first, second)


def test_one_map_a_place_in_the_edge_node_is_what_its_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The joined place with every walk's loops: four devices on walks of their own against
    lent copies and alone (the cover by points too), and against the runs whose joined
    walks' loops failed; the
    7-Scenes pair again against lending and against the first joined arm — as the table
    scripts print them from the committed CSVs."""
    monkeypatch.syspath_prepend(str(FIGURES))           # joined_place_table's sibling
    folder = FIGURES / "shared-map" / "joined"
    walks = _script("place_walks_table")
    for first, second, names in (
            ("lent", "join", ("lent copies", "joined")), ("alone", "join", ("alone", "joined")),
            ("alone", "lent", ("alone", "lent copies")),
            ("points-lent", "points-join", ("lent copies", "joined")),
            ("join-walk-loops-failing", "join",
             ("joined (the joined walks' loops failing)", "joined"))):
        printed = walks.table(folder / "place-walks" / f"{first}.csv",
                              folder / "place-walks" / f"{second}.csv", names=names)
        assert _missing("\n".join(printed)) == [], (first, second)
        assert "seeds 4, 5, 6, 7:" in printed[0]
    pair = _script("joined_place_table")
    two, later = folder / "two-ends", folder / "later"
    for printed in (pair.table(two / "lend.csv", two / "join-every-walk.csv"),
                    pair.table(two / "join.csv", two / "join-every-walk.csv",
                               names=("joined (the first walk's loops)",
                                      "joined (every walk's)")),
                    pair.table(later / "lend.csv", later / "join-every-walk.csv",
                               later / "alone.csv")):
        assert _missing("\n".join(printed)) == []
        assert printed[0] == "seeds 0, 1, 2, 4, 5, 6, 7"


def test_places_of_several_devices_and_renamed_points_are_what_their_commands_print(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Places of several devices joined: four devices on walks of their own, joined against
    lent copies, every joined run one place at the end (its CSV's ``places``) as the page
    says; the 7-Scenes pair's joined device with its points renamed in its next map update
    against the old ids and against lending, from the two ends and coming later — as the
    table scripts print them from the committed CSVs."""
    monkeypatch.syspath_prepend(str(FIGURES))           # joined_place_table's sibling
    folder = FIGURES / "shared-map" / "joined"
    several = folder / "places-of-several"
    printed = _script("place_walks_table").table(several / "lent.csv", several / "join.csv",
                                                  names=("lent copies", "joined"))
    assert _missing("\n".join(printed)) == [] and "seeds 4, 5, 6, 7:" in printed[0]
    for arm in ("join", "points-join"):
        with (several / f"{arm}.csv").open() as f:
            rows = list(csv.DictReader(f))
        assert rows and all(row["places"] == "1" and row["join"] == "1" for row in rows), arm
    pair = _script("joined_place_table")
    two, later = folder / "two-ends", folder / "later"
    for printed in (pair.table(two / "join-points-not-renamed.csv",
                               two / "join-points-renamed.csv",
                               names=("old point ids", "points renamed")),
                    pair.table(two / "lend-rerun.csv", two / "join-points-renamed.csv"),
                    pair.table(later / "lend-rerun.csv", later / "join-points-renamed.csv",
                               later / "alone-rerun.csv", lost=True)):
        assert printed[0] == "seeds 0, 1, 2, 4, 5, 6, 7"
        assert _missing("\n".join(printed)) == []
    # the figures the page quotes in its words: the renames coming later, and the lending
    # of 2026-12-07's machine against its device alone
    renamed = "\n".join(pair.table(later / "join-points-not-renamed.csv",
                                   later / "join-points-renamed.csv", later / "alone.csv",
                                   names=("old point ids", "points renamed")))
    assert "| +0.06 [-0.38, +0.50] |" in renamed and "| +0.29 [-0.41, +0.98] |" in renamed
    before = pair.table(later / "lend.csv", later / "join-points-renamed.csv",
                        later / "alone.csv", lost=True)
    assert "| +1.68 [+0.25, +3.11] |" in before[-2]
