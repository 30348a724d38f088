"""``bench.suite_cpu``: each test's CPU seconds, its own and those of the processes it waited
for, and the summary that ranks them — what finds the tests that cost ``make test`` its time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench import suite_cpu

REPO = Path(__file__).resolve().parents[1]

SPIN = "import time\nend = time.process_time() + 0.3\nwhile time.process_time() < end:\n    pass\n"


def test_each_tests_cpu_is_written_its_own_and_its_childrens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    tests = tmp_path / "test_spin.py"
    tests.write_text("import subprocess, sys\n\n"
                     f"def test_spins_here():\n    exec({SPIN!r})\n\n"
                     "def test_spins_in_a_child():\n"
                     f"    subprocess.run([sys.executable, '-c', {SPIN!r}], check=True)\n",
                     encoding="utf-8")
    out = tmp_path / "cpu.jsonl"
    env = dict(os.environ, PYTHONPATH=str(REPO), **{suite_cpu.OUT_ENV: str(out)})
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n0", "-p", "no:cacheprovider",
                          "-p", "bench.suite_cpu", "--rootdir", str(tmp_path), str(tests)],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    rows = {r["test"].split("::")[-1]: r for r in map(json.loads, out.read_text().splitlines())}
    assert set(rows) == {"test_spins_here", "test_spins_in_a_child"}
    assert rows["test_spins_here"]["own_s"] >= 0.25
    assert rows["test_spins_in_a_child"]["children_s"] >= 0.25
    assert rows["test_spins_in_a_child"]["own_s"] < 0.25
    monkeypatch.setattr("sys.argv", ["bench.suite_cpu", str(out), "--top", "1"])
    suite_cpu.main()
    printed = capsys.readouterr().out
    assert "2 tests" in printed and "test_spin.py" in printed
    listed = [line for line in printed.splitlines() if "::test_spins" in line]
    assert len(listed) == 1                                    # --top 1
    out.write_text("not json\n")
    with pytest.raises(SystemExit, match="not the plugin's JSON lines"):
        suite_cpu.main()
