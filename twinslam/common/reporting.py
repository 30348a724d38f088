"""Writing experiment results: one CSV per figure and a headless matplotlib."""

from __future__ import annotations

import csv
from pathlib import Path
from types import ModuleType


def write_csv(path: Path, header: list[str], rows: list[list[object]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (no display on CI machines or edge hosts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
