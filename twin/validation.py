"""Checks of user-supplied values shared by the parameter classes: one-line errors that
name the field and what is allowed."""
from __future__ import annotations

import math

from twin.errors import TwinError


def bounded_number(owner: str, name: str, v, lo: float, hi: float, unit: str = "", lo_open: bool = False) -> float:
    """``v`` as a float if it is a finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    ok = ok and (lo < v if lo_open else lo <= v) and v <= hi
    if not ok:
        bound = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise TwinError(f"{owner} {name} must be a number in {bound}{' ' + unit if unit else ''}, got {v!r}")
    return float(v)


def body_point(what: str, value) -> tuple[float, float, float]:
    """A point in the body frame (m, from the axle midpoint) within 1 m of the axle."""
    try:
        pos = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        pos = ()
    if len(pos) != 3 or not all(math.isfinite(v) and abs(v) <= 1.0 for v in pos):
        raise TwinError(f"{what} must be 3 finite coordinates in m within ±1 m of the axle, got {value!r}")
    return pos
