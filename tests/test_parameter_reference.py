"""The parameter reference a user reads (docs/parameters.md) is generated from the nodes'
declarations and is never stale: a parameter added, renamed or given a new default without
``twinslam parameters --write`` fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

from twinslam.cli.commands.parameters import NODES, REFERENCE, reference
from twinslam.cli.main import main


def test_the_committed_reference_is_what_the_declarations_say() -> None:
    assert REFERENCE.read_text(encoding="utf-8") == reference(), (
        "docs/parameters.md is stale: run `.venv/bin/twinslam parameters --write`")


def test_every_parameter_of_every_node_has_a_row_with_its_default() -> None:
    text = reference()
    for node, _, specs in NODES:
        section = text[text.index(f"## {node}\n"):]
        for spec in specs:
            assert f"| `{spec.name}` |" in section, (node, spec.name)
    assert "| `map_source` | string | `edge+local` |" in text
    assert "| `slot_frames` | int | `30` | 1 … 100000 |" in text


def test_check_fails_on_a_stale_page_and_write_mends_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "parameters.md"
    page.write_text(reference().replace("`edge+local`", "`edge`", 1), encoding="utf-8")
    assert main(["parameters", "--check", "--file", str(page)]) == 1
    assert "is stale" in capsys.readouterr().err
    assert main(["parameters", "--write", "--file", str(page)]) == 0
    assert main(["parameters", "--check", "--file", str(page)]) == 0
    assert page.read_text(encoding="utf-8") == reference()
