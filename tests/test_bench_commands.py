"""Every benchmark in ``bench/`` is a command a user runs from the README and BENCHMARKS.md:
each must still import against the code it measures and answer ``--help``. A bench that
stopped importing (a function it used was renamed) fails here, not the day someone needs its
figure."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

import bench

BENCH = Path(bench.__path__[0])


def _is_command(name: str) -> bool:
    """A module of ``bench/`` that defines ``main``: read from its source, not imported —
    importing every bench to find them loaded torch, pandas and sympy into every worker of the
    suite at collection (~3 s of CPU each), where only the worker that runs a bench's test
    needs its imports."""
    tree = ast.parse((BENCH / f"{name}.py").read_text(encoding="utf-8"))
    return any(isinstance(node, ast.FunctionDef) and node.name == "main" for node in tree.body)


#: the modules of ``bench/`` that are commands (the rest are shared helpers)
COMMANDS = sorted(m.name for m in pkgutil.iter_modules(bench.__path__) if _is_command(m.name))


def test_the_benches_are_found() -> None:
    assert {"edge_work", "edge_scaling", "loop_closer", "map_consistency"} <= set(COMMANDS)


#: importing the benches loads torch (bench.mbrl, bench.udt) and what the others measure: on the
#: worker that runs the suite's torch tests, the one that loads torch anyway
@pytest.mark.xdist_group("torch")
@pytest.mark.parametrize("name", COMMANDS)
def test_a_bench_answers_help(name: str, monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    module = importlib.import_module(f"bench.{name}")
    monkeypatch.setattr("sys.argv", [f"bench.{name}", "--help"])
    with pytest.raises(SystemExit) as stop:
        module.main()
    assert stop.value.code == 0
    assert "usage:" in capsys.readouterr().out
