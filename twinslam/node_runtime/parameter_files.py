"""Which sections of a ROS 2 parameter file reach a node, by rcl's rules.

rcl gives a node the sections keyed by its fully qualified name (``/ar1/device_tracker``), by a
pattern that matches it (``/**`` every node; ``/**/device_tracker`` that node in any namespace;
``*`` one name, ``**`` any number of them), and by its plain name (``device_tracker`` or
``/device_tracker``) only when it runs in the root namespace. A node started in a namespace
with a file keyed by plain names reads nothing from it and runs on its defaults without a word:
a fleet's devices did so with every parameter file until 2026-12-02. These functions let a node
say so at start.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import yaml

#: the argument that opens ROS's own arguments, the one that ends them, and a file's flag
ROS_ARGS, END_OF_ROS_ARGS, PARAMS_FILE = "--ros-args", "--", "--params-file"


def params_files(argv: Sequence[str]) -> list[Path]:
    """The ``--params-file`` paths among the ROS arguments of ``argv`` (each
    ``--ros-args`` … ``--`` stretch), in their order."""
    files, inside = [], False
    args = list(argv)
    for i, arg in enumerate(args):
        if arg == ROS_ARGS:
            inside = True
        elif arg == END_OF_ROS_ARGS:
            inside = False
        elif inside and arg == PARAMS_FILE and i + 1 < len(args):
            files.append(Path(args[i + 1]))
    return files


def key_reaches(key: str, node_fqn: str) -> bool:
    """Whether a parameter file's section ``key`` is read by the node whose fully qualified
    name is ``node_fqn`` (``/ar1/device_tracker``; ``/device_tracker`` in the root
    namespace)."""
    pattern = key if key.startswith("/") else f"/{key}"
    regex = ""
    for token in pattern.strip("/").split("/"):
        if token == "**":
            regex += r"(/[^/]+)*"
        else:
            regex += "/" + re.escape(token).replace(r"\*", "[^/]+")
    return re.fullmatch(regex, node_fqn) is not None


def unreached_sections(files: Sequence[Path], name: str, namespace: str) -> list[str]:
    """For node ``name`` in ``namespace``: each section of ``files`` that names it and does
    not reach it (``KEY in FILE``), from the files none of whose sections but ``/**``
    reaches it — a file keyed by plain names, read by a node in a namespace. Each file is
    judged on its own: ``ros2 launch`` adds a file of its own that does reach the node (the
    launch file's parameters), and the user's file still gives it nothing. Files that cannot
    be read are passed over: rcl has refused them before a node starts."""
    fqn = f"{namespace.rstrip('/')}/{name}"
    unreached = []
    for path in files:
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            continue
        if not isinstance(doc, dict):
            continue
        keys = [str(k) for k in doc if str(k) != "/**"]
        if any(key_reaches(k, fqn) for k in keys):
            continue
        unreached += [f"{k!r} in {path}" for k in keys if k.rsplit("/", 1)[-1] == name]
    return unreached
