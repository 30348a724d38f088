"""Appending runs to a result table: a new file gets its header, a file of the same columns
its rows appended, a file an older version wrote under fewer columns is rewritten under both
with every row it held."""

from __future__ import annotations

import csv
from pathlib import Path

from twinslam.reporting import append_csv_rows


def _read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def test_runs_appended_to_a_table_land_under_their_heads_and_old_rows_stay(
        tmp_path: Path) -> None:
    table = tmp_path / "runs" / "fleet_runs.csv"
    append_csv_rows(table, ("seed", "ate_m"), [{"seed": 0, "ate_m": 0.05}])
    append_csv_rows(table, ("seed", "ate_m"), [{"seed": 1, "ate_m": 0.04}])
    assert _read(table) == (["seed", "ate_m"], [{"seed": "0", "ate_m": "0.05"},
                                                {"seed": "1", "ate_m": "0.04"}])
    # a newer version's columns: the old rows keep their cells, the new column is empty there
    append_csv_rows(table, ("seed", "uploads", "ate_m"), [{"seed": 2, "uploads": 25,
                                                           "ate_m": 0.03}])
    header, rows = _read(table)
    assert header == ["seed", "ate_m", "uploads"]
    assert rows == [{"seed": "0", "ate_m": "0.05", "uploads": ""},
                    {"seed": "1", "ate_m": "0.04", "uploads": ""},
                    {"seed": "2", "ate_m": "0.03", "uploads": "25"}]
    # and the next run of the newer version appends under the merged header
    append_csv_rows(table, ("seed", "uploads", "ate_m"), [{"seed": 3, "uploads": 30}])
    assert _read(table)[1][-1] == {"seed": "3", "ate_m": "", "uploads": "30"}
