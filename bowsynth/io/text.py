"""How numbers are written for people and for JSON: one rule for a missing value (None or NaN) everywhere."""

from __future__ import annotations

import math

MISSING = "n/a"


def is_missing(v) -> bool:
    return v is None or (isinstance(v, float) and not math.isfinite(v))


def num(v, fmt: str = ".2e") -> str:
    """v in format `fmt` ('.3g', or a str.format pattern '{:.3g}'), or 'n/a' for a missing or non-finite value, or
    for anything that is not a number (a model file's record is data from outside: a string there is not shown)."""
    if is_missing(v) or isinstance(v, bool) or not isinstance(v, (int, float)):
        return MISSING
    return fmt.format(v) if "{" in fmt else format(v, fmt)


def jsonable(v):
    """v for JSON: NaN and infinities become null (JSON has no NaN), numpy scalars plain numbers, recursively."""
    if isinstance(v, dict):
        return {k: jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    if hasattr(v, "item") and callable(v.item) and getattr(v, "ndim", 1) == 0:
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v
