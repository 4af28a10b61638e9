"""Sensor faults to inject: dropouts, stuck outputs, outlier spikes, a change of latency.

Each fault names the sensor it hits: ``"gyro"``, ``"accel"``, ``"imu"`` (both),
``"encoders"`` or ``"all"``. Faults act on samples as they are produced (times are the
sample times, s); the latency change acts on samples produced from ``time`` on.

* :class:`Dropout`: no sample reaches the estimator in [start, start + duration).
* :class:`Stuck`: the output repeats the last good sample over the window.
* :class:`Spikes`: each sample in the window is, with probability rate·Δt, an outlier:
  every axis is offset by ±``magnitude`` (random signs; the IMU's range still clips it).
* :class:`LatencyChange`: from ``time`` on the sensor reports ``latency`` s late
  (a whole number of control periods) while the estimator still assumes the spec's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from twin.errors import TwinError

SENSOR_GROUPS = {"gyro": ("gyro",), "accel": ("accel",), "imu": ("gyro", "accel"), "encoders": ("encoders",),
                 "all": ("gyro", "accel", "encoders")}


def _check_sensor(kind: str, sensor) -> tuple[str, ...]:
    if sensor not in SENSOR_GROUPS:
        raise TwinError(f"{kind} sensor must be one of {', '.join(SENSOR_GROUPS)}, got {sensor!r}")
    return SENSOR_GROUPS[sensor]


def _time(kind: str, name: str, v, allow_inf: bool = False) -> float:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0 and (math.isfinite(v) or
                                                                                  (allow_inf and v == math.inf))
    if not ok:
        raise TwinError(f"{kind} {name} must be a time ≥ 0 in s{' (or inf)' if allow_inf else ''}, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class _Window:
    sensor: str
    start: float = 0.0
    duration: float = math.inf

    def __post_init__(self):
        kind = type(self).__name__
        _check_sensor(kind, self.sensor)
        object.__setattr__(self, "start", _time(kind, "start", self.start))
        object.__setattr__(self, "duration", _time(kind, "duration", self.duration, allow_inf=True))

    @property
    def sensors(self) -> tuple[str, ...]:
        return SENSOR_GROUPS[self.sensor]

    def active(self, t: float) -> bool:
        return self.start - 1e-9 <= t < self.start + self.duration - 1e-9


@dataclass(frozen=True)
class Dropout(_Window):
    """No sample is delivered while active."""


@dataclass(frozen=True)
class Stuck(_Window):
    """The output repeats the last sample before the window while active."""


@dataclass(frozen=True)
class Spikes(_Window):
    """Outliers: probability ``rate`` (1/s) × sample interval per sample, offset ±``magnitude``
    on every axis (rad/s, m/s² or rad of wheel angle, the sensor's unit). An encoder's glitch
    is a whole number of counts: ±``magnitude`` rounded to counts, at least one."""

    rate: float = 2.0
    magnitude: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        for n, v in (("rate", self.rate), ("magnitude", self.magnitude)):
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
                raise TwinError(f"Spikes {n} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class LatencyChange:
    """From ``time`` (s) on, ``sensor`` reports ``latency`` s late."""

    sensor: str
    time: float
    latency: float

    def __post_init__(self):
        _check_sensor("LatencyChange", self.sensor)
        object.__setattr__(self, "time", _time("LatencyChange", "time", self.time))
        object.__setattr__(self, "latency", _time("LatencyChange", "latency", self.latency))
        if self.latency > 1.0:
            raise TwinError(f"LatencyChange latency must be at most 1 s, got {self.latency!r}")

    @property
    def sensors(self) -> tuple[str, ...]:
        return SENSOR_GROUPS[self.sensor]


FAULT_TYPES = (Dropout, Stuck, Spikes, LatencyChange)


def fault_windows(faults) -> list[tuple[str, float, float]]:
    """(name, start s, end s) of each fault, for figures and overlays: e.g. ("IMU dropout",
    2.0, 2.2); a latency change, which lasts, ends at inf."""
    out = []
    for f in faults or ():
        sensor = {"imu": "IMU", "all": "all sensors"}.get(f.sensor, f.sensor)
        if isinstance(f, LatencyChange):
            out.append((f"{sensor} latency {1e3 * f.latency:.0f} ms", f.time, math.inf))
        else:
            out.append((f"{sensor} {type(f).__name__.lower()}", f.start, f.start + f.duration))
    return out
