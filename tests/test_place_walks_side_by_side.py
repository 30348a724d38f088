"""``bench.place_walks --baseline``: both trees make the run the user asked for, and only the
side-by-side's own options (the commit, the rounds, the tables every run lands in) stay
behind."""

from __future__ import annotations

from bench.place_walks import _run_options


def test_both_trees_get_every_option_of_the_run_but_the_side_by_sides_own() -> None:
    asked = ["synthetic-corridor:900", "--devices", "8", "--baseline", "d5e41a1", "--after",
             "150", "--rounds=2", "--csv", "out.csv", "--device", "map_source=edge",
             "--csv=again.csv", "--covered-m", "0.3", "--frames-csv", "frames.csv", "--frames",
             "900"]
    assert _run_options(asked) == ["synthetic-corridor:900", "--devices", "8", "--after",
                                   "150", "--device", "map_source=edge", "--covered-m", "0.3",
                                   "--frames", "900"]
