"""Every benchmark in ``bench/`` is a command a user runs from the README and BENCHMARKS.md:
each must still import against the code it measures and answer ``--help``. A bench that
stopped importing (a function it used was renamed) fails here, not the day someone needs its
figure."""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import bench

#: the modules of ``bench/`` that are commands (the rest are shared helpers)
COMMANDS = sorted(m.name for m in pkgutil.iter_modules(bench.__path__)
                  if hasattr(importlib.import_module(f"bench.{m.name}"), "main"))


def test_the_benches_are_found() -> None:
    assert {"edge_work", "edge_scaling", "loop_closer", "map_consistency"} <= set(COMMANDS)


@pytest.mark.parametrize("name", COMMANDS)
def test_a_bench_answers_help(name: str, monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    module = importlib.import_module(f"bench.{name}")
    monkeypatch.setattr("sys.argv", [f"bench.{name}", "--help"])
    with pytest.raises(SystemExit) as stop:
        module.main()
    assert stop.value.code == 0
    assert "usage:" in capsys.readouterr().out
