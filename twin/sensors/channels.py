"""The parts of a sensor type's entry (:mod:`twin.sensors.types`): a channel (a named reading
with its unit and components), a key of a scenario's ``[sensors.<type>]`` table (unit, range,
default), and what the loop knows at a control instant for a sensor's truth."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

from twin.errors import TwinError, shown


@dataclass(frozen=True)
class Channel:
    """One named reading: ``name``, SI ``unit``, ``columns`` (the names of its components, as its
    log stream's columns after ``t``; the shape is ``(len(columns),)``) and ``doc``."""

    name: str
    unit: str
    columns: tuple
    doc: str = ""

    @property
    def shape(self) -> tuple:
        return (len(self.columns),)


@dataclass(frozen=True)
class SpecKey:
    """One key of ``[sensors.<type>]``: SI ``unit``, the allowed range [``lo``, ``hi``] (``lo_open``:
    (lo, hi]), ``default`` (None: absent, the spec's own rule), ``kind`` "float" or "int", ``doc``."""

    unit: str
    lo: float
    hi: float
    default: Any
    doc: str
    lo_open: bool = False
    kind: str = "float"

    def check(self, key: str, v, prefix: str):
        """``v`` as this key's number, or one line: ``<prefix> <key> must be ..., got ...``."""
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        if ok and self.kind == "int":
            ok = isinstance(v, int)
        if ok:
            ok = (v > self.lo if self.lo_open else v >= self.lo) and v <= self.hi
        if not ok:
            raise TwinError(f"{prefix} {key} must be {self.allowed()}, got {shown(v)}")
        return int(v) if self.kind == "int" else float(v)

    def allowed(self) -> str:
        u = f" {self.unit}" if self.unit and self.unit != "1" else ""
        if self.kind == "int":
            return f"an integer from {self.lo:g} to {self.hi:g}{u}"
        if self.lo_open:
            return f"a number > {self.lo:g} and ≤ {self.hi:g}{u}"
        return f"a number ≥ {self.lo:g} and ≤ {self.hi:g}{u}"


class Sources(NamedTuple):
    """What the loop knows at a control instant, for a sensor type's ``truth``: ``plant`` the plant
    (for an optional member of its own, e.g. ``motor_current``), ``truth`` its
    :class:`~twin.plant.base.GroundTruth` now, ``actuation`` what its motors did over the period
    that just ended (None at instant 0), ``motor`` the :class:`~twin.actuators.DCMotorParams` it
    drives its wheels through (None: ideal torque sources)."""

    plant: Any
    truth: Any
    actuation: Any
    motor: Any




def whole_steps(x: float, message: str) -> int:
    """``x`` as a whole number (a ratio of rates, a latency in control periods), or ``message``
    as a one-line :class:`~twin.errors.TwinError`."""
    if not math.isfinite(x):  # a rate of 5e-324 Hz: the ratio overflows
        raise TwinError(message)
    k = round(x)
    if abs(x - k) > 1e-9 * max(1.0, abs(x)):
        raise TwinError(message)
    return int(k)


__all__ = ["Channel", "Sources", "SpecKey", "whole_steps"]
