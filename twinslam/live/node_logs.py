"""A run's node logs kept with its figures: what the edge said of each loop, merge, restore
or refused upload, which a sweep's console or a fleet's status lines do not show."""

from __future__ import annotations

from pathlib import Path


def write_logs(logs: dict[str, str], path: Path) -> None:
    """Every node's log of a run (node name → its stderr) in one file, node by node."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"===== {name} =====\n{text.rstrip()}\n\n"
                            for name, text in sorted(logs.items())), encoding="utf-8")
