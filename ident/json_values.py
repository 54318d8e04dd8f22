"""Typed reads of values from a parsed JSON (or TOML) document: a number that is a number, an object that
is an object, row counts that are counts. Each raises ValueError naming the key it was given, so a
reader's error says which entry of which file is wrong."""
from __future__ import annotations

import math
from typing import Mapping


def json_object(x, where: str) -> Mapping:
    """``x`` if it is a JSON object. Raises ValueError naming ``where``."""
    if not isinstance(x, Mapping):
        raise ValueError(f"{where} must be an object, got {type(x).__name__}")
    return x


def json_number(x, where: str) -> float:
    """``x`` as a finite float if it is a JSON number (not a boolean, string or null). Raises ValueError
    naming ``where``."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ValueError(f"{where} must be a number, got {x!r}")
    value = float(x)
    if not math.isfinite(value):
        raise ValueError(f"{where} must be finite, got {value!r}")
    return value


def row_counts(x, where: str) -> dict[str, int]:
    """{channel: row count} with non-negative integers. Raises ValueError naming ``where``."""
    out = {}
    for k, v in json_object(x, where).items():
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ValueError(f"{where}.{k} must be a non-negative integer, got {v!r}")
        out[k] = v
    return out
