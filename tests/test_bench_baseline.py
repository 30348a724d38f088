"""A side-by-side benchmark (``--baseline COMMIT``) runs the baseline's tree in a worktree of
its own: a sequence given by a path relative to here must name the same folder there, where
the relative path named nothing and the baseline's run failed."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.baseline import absolute_paths


def test_a_relative_sequence_path_reaches_the_baseline_tree_absolute(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "data" / "kitchen").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "data")
    kitchen = str(tmp_path / "data" / "kitchen")
    assert absolute_paths("kitchen") == kitchen
    assert absolute_paths("kitchen:600,synthetic-corridor:1000,synthetic") == \
        f"{kitchen}:600,synthetic-corridor:1000,synthetic"
    # what names nothing here is forwarded as it is: options, numbers, named worlds
    assert absolute_paths("--devices") == "--devices" and absolute_paths("9") == "9"
    assert absolute_paths("missing/folder:3") == "missing/folder:3"
