"""ROS 2 name expansion and remapping (REP 144 / design article "Topic and Service name mapping").

A node sees names in three forms: absolute (``/camera/image_raw``), relative (``image_raw``,
expanded under the node's namespace) and private (``~/pose``, expanded under the node's fully
qualified name). Remap rules are matched against the *expanded* name, as rcl does.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class NameError_(ValueError):
    """An invalid node name, namespace or topic name."""


def validate_node_name(name: str) -> str:
    if not _TOKEN.match(name):
        raise NameError_(f"invalid node name {name!r}: use letters, digits and '_' "
                         "and do not start with a digit")
    return name


def normalize_namespace(namespace: str) -> str:
    """``''`` and ``'ns'`` become ``'/'`` and ``'/ns'``; tokens are validated."""
    ns = "/" + namespace.strip("/") if namespace not in ("", "/") else "/"
    for token in ns.strip("/").split("/"):
        if token and not _TOKEN.match(token):
            raise NameError_(f"invalid namespace {namespace!r}: bad token {token!r}")
    return ns


def expand_topic_name(name: str, node_name: str, namespace: str) -> str:
    """Fully qualified topic name of ``name`` as seen by node ``namespace/node_name``."""
    if not name:
        raise NameError_("topic name must not be empty")
    ns = normalize_namespace(namespace)
    base = ns.rstrip("/")
    if name.startswith("~"):
        rest = name[1:].lstrip("/")
        full = f"{base}/{node_name}" + (f"/{rest}" if rest else "")
    elif name.startswith("/"):
        full = name
    else:
        full = f"{base}/{name}"
    full = full.rstrip("/") or "/"
    for token in full.strip("/").split("/"):
        if not _TOKEN.match(token):
            raise NameError_(f"invalid topic name {name!r} (expanded to {full!r}): "
                             f"bad token {token!r}")
    return full


@dataclass(frozen=True)
class RemapRule:
    """``[node:]from:=to`` from the command line; ``node`` limits the rule to one node."""

    source: str
    target: str
    node: str | None = None

    @classmethod
    def parse(cls, text: str) -> RemapRule:
        if ":=" not in text:
            raise NameError_(f"remap rule {text!r} lacks ':='")
        lhs, target = text.split(":=", 1)
        node = None
        if ":" in lhs:
            node, lhs = lhs.split(":", 1)
        if not lhs or not target:
            raise NameError_(f"remap rule {text!r} has an empty side")
        return cls(lhs, target, node)

    def applies_to(self, node_name: str) -> bool:
        return self.node is None or self.node == node_name


def remap_topic(full_name: str, rules: list[RemapRule], node_name: str, namespace: str) -> str:
    """Apply the first matching remap rule (rcl semantics) to an expanded topic name."""
    for rule in rules:
        if rule.source.startswith("__") or not rule.applies_to(node_name):
            continue
        if expand_topic_name(rule.source, node_name, namespace) == full_name:
            return expand_topic_name(rule.target, node_name, namespace)
    return full_name


def dds_topic_name(full_name: str) -> str:
    """ROS topic ``/a/b`` travels as DDS topic ``rt/a/b`` (the ROS 2 topic prefix)."""
    return "rt" + full_name
