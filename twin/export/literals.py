"""C text for numbers: every constant written so that the compiler reads back the very value
the twin computed (hex float literals: exact, no decimal rounding).

``precision`` is ``"float64"`` (C ``double``) or ``"float32"`` (C ``float``: the value rounded
once to the nearest float32, written with the ``f`` suffix, so that no expression is promoted
to double on a microcontroller whose FPU has single precision only).
"""
from __future__ import annotations

import math
from importlib import resources

import numpy as np

from twin.errors import TwinError

PRECISIONS = ("float64", "float32")
C_TYPES = {"float64": "double", "float32": "float"}


def check_precision(precision: str) -> str:
    if precision not in PRECISIONS:
        raise TwinError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return precision


def literal(value: float, precision: str = "float64") -> str:
    """``value`` as a C floating literal of ``precision`` (exact hex form)."""
    v = float(value)
    if not math.isfinite(v):
        raise TwinError(f"cannot export a non-finite constant ({v!r}): the design has a NaN or an infinity")
    if precision == "float32":
        f = np.float32(v)
        if not np.isfinite(f):
            raise TwinError(f"constant {v!r} overflows float32; export with precision float64")
        return float(f).hex() + "f"
    check_precision(precision)
    return v.hex()


def array(name: str, values, precision: str = "float64", ctype: str = "mtwip_real", static: bool = True) -> str:
    """``static const ctype name[n] = {...};`` for the flattened ``values``."""
    flat = np.ravel(np.asarray(values, dtype=float))
    body = ", ".join(literal(v, precision) for v in flat)
    return f"{'static ' if static else ''}const {ctype} {name}[{len(flat)}] = {{{body}}};"


def static_text(name: str) -> str:
    """A file of the C that is not generated, as it stands in the package (twin/export/c/NAME)."""
    return resources.files("twin.export").joinpath("c", name).read_text(encoding="utf-8")


def integer(value: int) -> str:
    return str(int(value))


__all__ = ["C_TYPES", "PRECISIONS", "array", "check_precision", "integer", "literal", "static_text"]
