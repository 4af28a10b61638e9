"""The table of sensor types: what each gives (its channels, with units and shapes), what a
scenario says of it (its ``[sensors.<type>]`` keys, with units and ranges), how it is built
and how it is read each control period.

A *channel* is one named reading of a :class:`~twin.sensors.Measurement`: ``gyro`` (3,) rad/s,
``accel`` (3,) m/s², ``encoders`` (2,) rad, ``motor_current`` (2,) A. Estimators read the three
core channels as attributes (``meas.gyro``) and any channel by name (``meas["motor_current"]``,
``meas.channels``); a channel that is absent from a run, or gave nothing new at an instant, is
None.

A *sensor type* is one module plus one entry of :data:`SENSOR_TYPES`:

* the IMU and the encoders (``core``): built and read by :class:`~twin.sensors.SensorSuite` on
  its fixed path (the figures of ``[sensors]``, :mod:`twin.sensors.specs`), their rows in the
  log format's own streams (imu.csv, encoders.csv);
* every other type (the motor current, :mod:`twin.sensors.motor_current`): off unless a
  scenario's ``[sensors.<type>]`` (or a log's ``[sensors.<type>]`` / ``[streams.<type>]``) turns
  it on. Its entry gives the spec class (a frozen dataclass built from the table's keys, one-line
  errors naming the key), the reader (``reader(spec, control_rate, rng)``: its noise drawn from
  its own child of the run's generator), ``truth(sources)`` (what the loop hands the reader at
  each control instant, from the plant's truth and actuation), and its log stream: ``<type>.csv``
  with the channel's columns, declared in log.toml as ``[streams.<type>]`` with the figures in
  ``[sensors.<type>]`` (:mod:`twin.logs.format`).

Adding a type: its module (spec, reader, truth function) and an entry below; the scenario
schema, the suite, the loop, the recorder, the log format and the replay take it from here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from twin.errors import TwinError, shown
from twin.sensors import motor_current as _motor_current
from twin.sensors.channels import Channel, SpecKey, Sources  # noqa: F401  (named here too: the table's parts)


@dataclass(frozen=True)
class SensorType:
    """An entry of :data:`SENSOR_TYPES` (see the module docstring)."""

    name: str
    doc: str
    channels: tuple  # Channel, ...
    core: bool = False
    keys: dict = field(default_factory=dict)  # key -> SpecKey, the [sensors.<type>] figures
    spec: Any = None  # the spec class: spec(**figures); None for a core type
    reader: Any = None  # reader(spec, control_rate, rng), for a non-core type
    truth: Callable | None = None  # truth(sources) -> the true values of each channel, at an instant
    needs: str = ""  # what the plant must have for it (a one-line error otherwise), e.g. "motor"

    def build(self, table: dict, where: str = ""):
        """The spec of ``table`` (key -> value; absent keys at the spec's defaults), or a one-line
        :class:`~twin.errors.TwinError`: ``<where> [sensors.<type>] <key> must be ...`` (``where``
        the file, say)."""
        prefix = f"{where}: [sensors.{self.name}]" if where else f"[sensors.{self.name}]"
        if not isinstance(table, dict):
            raise TwinError(f"{prefix}: {shown(table)}; allowed: a table of {key_list(self)}")
        figures = {}
        for k, v in table.items():
            if k not in self.keys:
                raise TwinError(f"{prefix} {k}: unknown key; allowed: {key_list(self)}")
            if v is None:
                continue
            figures[k] = self.keys[k].check(k, v, prefix)
        try:
            return self.spec(**figures)
        except TwinError as exc:  # a rule between keys (a resolution above the full scale)
            raise TwinError(f"{where}: {exc}" if where else str(exc)) from None


def key_list(t: SensorType) -> str:
    """``key (unit)`` of each of a type's keys, for a message listing what is allowed."""
    return ", ".join(f"{k} ({s.unit})" if s.unit else k for k, s in t.keys.items())


# ---- the table -----------------------------------------------------------------------------------
GYRO = Channel("gyro", "rad/s", ("x", "y", "z"), "angular velocity, body axes (mean over the sample interval)")
ACCEL = Channel("accel", "m/s²", ("x", "y", "z"), "specific force, body axes (mean over the sample interval)")
ENCODERS = Channel("encoders", "rad", ("left", "right"), "each wheel's angle relative to the body since power-up, "
                   "whole counts")

SENSOR_TYPES: dict[str, SensorType] = {
    "imu": SensorType("imu", "the body's IMU: gyro and accelerometer ([sensors] imu, imu_rate, imu_latency, "
                      "[sensors.gyro], [sensors.accel]; twin/sensors/specs.py)", (GYRO, ACCEL), core=True),
    "encoders": SensorType("encoders", "incremental encoders on both motor shafts ([sensors] encoder_counts, "
                           "encoder_latency)", (ENCODERS,), core=True),
    "motor_current": SensorType(
        "motor_current", _motor_current.DOC, (_motor_current.CHANNEL,), keys=_motor_current.KEYS,
        spec=_motor_current.MotorCurrentSpec, reader=_motor_current.MotorCurrentSensor,
        truth=_motor_current.true_current, needs="motor"),
}
"""Sensor type name → :class:`SensorType` (see the module docstring)."""

CORE_CHANNELS = ("gyro", "accel", "encoders")  # the Measurement's own fields


def extra_types() -> tuple:
    """The non-core types (those a scenario or a log turns on), in table order."""
    return tuple(t for t in SENSOR_TYPES.values() if not t.core)


def channel(name: str) -> Channel:
    """The channel ``name`` of any type, or a one-line error listing every channel."""
    for t in SENSOR_TYPES.values():
        for c in t.channels:
            if c.name == name:
                return c
    raise TwinError(f"no sensor channel {shown(name)}; channels: {', '.join(channel_names())}")


def channel_names() -> tuple:
    return tuple(c.name for t in SENSOR_TYPES.values() for c in t.channels)


def type_of(spec) -> SensorType:
    """The table entry whose spec class ``spec`` is an instance of."""
    for t in extra_types():
        if isinstance(spec, t.spec):
            return t
    raise TwinError(f"{shown(spec)} is no sensor type's specification; types: "
                    f"{', '.join(t.name for t in extra_types())} (twin.sensors.types.SENSOR_TYPES)")


__all__ = ["ACCEL", "CORE_CHANNELS", "Channel", "ENCODERS", "GYRO", "SENSOR_TYPES", "SensorType", "Sources", "SpecKey",
           "channel", "channel_names", "extra_types", "key_list", "type_of"]
