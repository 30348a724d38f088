"""``twinslam parameters``: the nodes' parameter reference, generated from their declarations.

Every node lists its parameters once, as :class:`~twinslam.node_runtime.parameters.ParamSpec` s
(name, default, description, range, whether it changes live); ``ros2 param describe`` reads the
same declarations from a running node. This command writes them as one Markdown page
(``docs/parameters.md``), so the reference a user reads is never older than the code:
``--check`` fails when the committed page differs from what the declarations say.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from twinslam.cli.console import Subparsers
from twinslam.live.run_checks import NODE_PARAMETERS
from twinslam.node_runtime.parameters import ParamSpec

#: the nodes in the order a run starts them, each with what it is for
NODES: tuple[tuple[str, str, Sequence[ParamSpec]], ...] = (
    ("sequence_player", "replays an RGB-D dataset folder, a recorded bag or a synthetic world "
     "as camera topics", NODE_PARAMETERS["sequence_player"]),
    ("device_tracker", "tracks the camera against the edge's map and uploads the frames the "
     "edge asks for", NODE_PARAMETERS["device_tracker"]),
    ("edge_mapper", "keeps the keyframe map, decides uploads and evictions, optimises and "
     "sends the map back", NODE_PARAMETERS["edge_mapper"]),
    ("udt_node", "the user digital twin: learns the uplink from throughput reports",
     NODE_PARAMETERS["udt_node"]),
)
REFERENCE = Path(__file__).resolve().parents[3] / "docs" / "parameters.md"


def _value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return "[" + ", ".join(value) + "]"
    if isinstance(value, str):
        return f'"{value}"' if value == "" else value
    return f"{value:g}" if isinstance(value, float) else str(value)


def _type(spec: ParamSpec) -> str:
    return {bool: "bool", int: "int", float: "double", str: "string",
            tuple: "string[]"}[type(spec.default)]


def _range(spec: ParamSpec) -> str:
    if spec.low is None and spec.high is None:
        return ""
    low = "" if spec.low is None else _value(spec.low)
    high = "" if spec.high is None else _value(spec.high)
    return f"{low} … {high}"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def reference() -> str:
    """The whole page, as ``--write`` writes it."""
    lines = ["# Node parameters", "",
             "Generated from the nodes' parameter declarations by `twinslam parameters --write` "
             "(a test fails when this page is stale); `ros2 param describe NODE NAME` shows the "
             "same description and range on a running node. The defaults are the default "
             "device's (`twinslam/slot_protocol/default_device.py`); `config/twinslam.yaml` "
             "writes them out and `config/paper-table1.yaml` is the paper's Table I device. "
             "*live*: `ros2 param set` changes it while the node runs; the others are read "
             "once at start.", "",
             "**Contents:** " + " · ".join(f"[`{name}`](#{name})" for name, _, _ in NODES), ""]
    for name, what, specs in NODES:
        lines += [f"## {name}", "", f"`{name}` {what}.", "",
                  "| parameter | type | default | range | live | description |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| `{s.name}` | {_type(s)} | `{_cell(_value(s.default))}` | {_range(s)} | "
                  f"{'yes' if s.live else ''} | {_cell(s.description)} |" for s in specs]
        lines.append("")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    text = reference()
    if args.check:
        committed = args.file.read_text(encoding="utf-8") if args.file.is_file() else ""
        if committed != text:
            print(f"{args.file} is stale: `twinslam parameters --write` regenerates it from "
                  "the nodes' declarations", file=sys.stderr)
            return 1
        print(f"{args.file} matches the nodes' declarations")
        return 0
    if args.write:
        args.file.write_text(text, encoding="utf-8")
        print(f"wrote {args.file} ({sum(len(s) for _, _, s in NODES)} parameters of "
              f"{len(NODES)} nodes)")
        return 0
    print(text, end="")
    return 0


def register(sub: Subparsers) -> None:
    cmd = sub.add_parser("parameters", help="the nodes' parameter reference, generated from "
                         "their declarations (Markdown)")
    mode = cmd.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true",
                      help="write it to --file instead of printing it")
    mode.add_argument("--check", action="store_true",
                      help="exit 1 when --file differs from what the declarations say")
    cmd.add_argument("--file", type=Path, default=REFERENCE,
                     help="the page --write and --check use; default docs/parameters.md")
    cmd.set_defaults(func=run)
