"""Hypothesis strategies that build random messages of any registered type from its fields."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import strategies as st

from msg_schemas import message_class, typestore
from msg_schemas.registry import PRIMITIVE_DTYPES

_INT_RANGES = {"int8": (-128, 127), "uint8": (0, 255), "byte": (0, 255), "char": (0, 255),
               "int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
               "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1),
               "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}
MAX_LEN = 6


def _scalar(base: str) -> st.SearchStrategy[Any]:
    if base == "bool":
        return st.booleans()
    if base == "string":
        return st.text(max_size=12)
    if base == "float32":
        return st.floats(width=32, allow_nan=False)
    if base == "float64":
        return st.floats(allow_nan=False)
    lo, hi = _INT_RANGES[base]
    return st.integers(lo, hi)


def field_strategy(node: tuple[Any, Any]) -> st.SearchStrategy[Any]:
    kind, detail = int(node[0]), node[1]
    if kind == 1:
        return _scalar(detail[0])
    if kind == 2:
        return message_strategy(detail)
    sub, count = detail
    size = st.just(count) if kind == 3 else st.integers(0, MAX_LEN)
    if int(sub[0]) == 1 and sub[1][0] in PRIMITIVE_DTYPES:
        dtype = PRIMITIVE_DTYPES[sub[1][0]]
        return size.flatmap(lambda n: st.lists(_scalar(sub[1][0]), min_size=n, max_size=n)
                            .map(lambda xs: np.array(xs, dtype=dtype)))
    return size.flatmap(lambda n: st.lists(field_strategy(sub), min_size=n, max_size=n))


def message_strategy(name: str) -> st.SearchStrategy[Any]:
    _consts, defs = typestore().fielddefs[name]
    cls = message_class(name)
    return st.fixed_dictionaries({fname: field_strategy(node) for fname, node in defs}) \
        .map(lambda kw: cls(**kw))
