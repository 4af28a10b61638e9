"""A scenario's sensors: the ``[sensors]`` keys as the true specification the twin simulates
and the believed one the estimator is built with.

True: the preset ``sensors.imu`` (:data:`twin.sensors.specs.IMU_PRESETS`) with the figures
of ``[sensors.gyro]`` and ``[sensors.accel]`` replacing its own, mounted at
``sensors.imu_position``, at ``sensors.imu_rate`` and ``sensors.imu_latency``; the encoders
and faults; the sensors beyond them (:data:`twin.sensors.types.SENSOR_TYPES`: the motor current)
that ``[sensors.<type>]`` turns on (:func:`extra_specs`). Believed (``[sensors.believed]``): the
true specification, or the preset ``believed.imu``, with the figures of
``[sensors.believed.gyro]`` / ``[...accel]`` replacing those; rate, latency, mounting point,
encoders, faults and the extra sensors are the true ones.

:func:`problems` finds what the schema's per-key ranges cannot: a full scale the noise
would saturate (:meth:`~twin.sensors.specs.TriadSpec.range_problem`) and a mounting point
outside the body's box (:func:`twin.plant.urdf.body_box`).
"""
from __future__ import annotations

from dataclasses import replace

from twin.errors import TwinError
from twin.plant.urdf import body_box
from twin.sensors import Dropout, LatencyChange, SensorConfig, Spikes, Stuck
from twin.sensors.specs import DEFAULT_IMU, IMU_PRESETS, EncoderSpec, ImuSpec, TriadSpec
from twin.sensors.types import extra_types

TRIADS = ("gyro", "accel")


def _overridden(base: TriadSpec, table: dict) -> TriadSpec:
    given = {k: v for k, v in table.items() if v is not None}
    return replace(base, **given) if given else base


def true_triads(s: dict) -> tuple[TriadSpec, TriadSpec]:
    """(gyro, accelerometer) the sensors simulate, from the validated ``[sensors]`` table ``s``."""
    preset = IMU_PRESETS[s["imu"]]
    return tuple(_overridden(base, s[t]) for base, t in zip(preset, TRIADS))


def believed_triads(s: dict) -> tuple[TriadSpec, TriadSpec]:
    """(gyro, accelerometer) the estimator believes in."""
    b = s["believed"]
    preset = IMU_PRESETS[b["imu"]] if b["imu"] is not None else true_triads(s)
    return tuple(_overridden(base, b[t]) for base, t in zip(preset, TRIADS))


def has_belief(s: dict) -> bool:
    """True if ``[sensors.believed]`` says anything (else the estimator believes the truth)."""
    b = s["believed"]
    return b["imu"] is not None or any(v is not None for t in TRIADS for v in b[t].values())


def _faults(data: dict) -> tuple:
    out = []
    for f in data["faults"]:
        if f["kind"] == "latency":
            out.append(LatencyChange(f["sensor"], f["start"], f["latency"]))
        elif f["kind"] == "spikes":
            out.append(Spikes(f["sensor"], f["start"], f["duration"], rate=f["rate"], magnitude=f["magnitude"]))
        else:
            out.append({"dropout": Dropout, "stuck": Stuck}[f["kind"]](f["sensor"], f["start"], f["duration"]))
    return tuple(out)


def extra_specs(s: dict) -> tuple:
    """The specs of the sensors beyond the IMU and encoders that the validated ``[sensors]``
    table ``s`` turns on: ``[sensors.<type>]`` with ``enabled = true``, or with any figure given
    and ``enabled`` absent; () when none (the default). A figure that the type's spec refuses
    (a resolution above the full scale, say) is one line naming the key."""
    out = []
    for t in extra_types():
        table = s.get(t.name) or {}
        figures = {k: v for k, v in table.items() if k != "enabled" and v is not None}
        on = table.get("enabled")
        if on is False or (on is None and not figures):
            continue
        out.append(t.build(figures))
    return tuple(out)


def _config(data: dict, triads) -> SensorConfig:
    s = data["sensors"]
    position = DEFAULT_IMU.position if s["imu_position"] is None else tuple(s["imu_position"])
    orientation = (0.0, 0.0, 0.0) if s["imu_orientation"] is None else tuple(s["imu_orientation"])
    imu = ImuSpec(gyro=triads[0], accel=triads[1], position=position, rate=s["imu_rate"], latency=s["imu_latency"],
                  orientation=orientation)
    return SensorConfig(imu=imu, encoders=EncoderSpec(s["encoder_counts"], s["encoder_latency"]),
                        faults=_faults(data), extra=extra_specs(s))


def true_config(data: dict) -> SensorConfig | None:
    """The sensors the twin simulates (None: ideal sensing)."""
    if data["sensors"]["sensing"] == "ideal":
        return None
    return _config(data, true_triads(data["sensors"]))


def believed_config(data: dict) -> SensorConfig | None:
    """The sensors as the estimator believes them (None: ideal sensing); the true
    configuration itself when ``[sensors.believed]`` is empty."""
    s = data["sensors"]
    if s["sensing"] == "ideal":
        return None
    if not has_belief(s):
        return true_config(data)
    return _config(data, believed_triads(s))


def problems(data: dict, params, body=None) -> str | None:
    """The first sensor problem as ``"key: what is wrong; allowed: ..."``, or None.

    ``params``: the true plant's :class:`~twin.params.RobotParams` (its body box holds the IMU)."""
    s = data["sensors"]
    for where, triads in (("sensors", true_triads(s)), ("sensors.believed", believed_triads(s))):
        for t, triad in zip(TRIADS, triads):
            problem = triad.range_problem(s["imu_rate"])
            if problem:
                return f"{where}.{t}.full_scale: {problem}"
    try:
        specs = extra_specs(s)
    except TwinError as exc:
        return str(exc)
    rate = data["rates"]["control"]
    for spec in specs:
        try:
            spec.steps(rate)
        except TwinError as exc:
            return f"{exc}; allowed with rates.control = {rate:g} Hz"
    plant = data.get("plant") or {}
    needs_motor = [t.name for t in extra_types() if t.needs == "motor" and any(isinstance(x, t.spec) for x in specs)]
    if needs_motor and (plant.get("motor") == "ideal" or plant.get("model") == "analytic"):
        why = 'plant.motor = "ideal"' if plant.get("motor") == "ideal" else 'plant.model = "analytic"'
        return (f"sensors.{needs_motor[0]}: needs DC motors, and {why} drives the wheels with ideal torque sources "
                f"(no motor current); allowed: plant.motor = \"dc\" on the bullet plant, or no "
                f"[sensors.{needs_motor[0]}]")
    if s["imu_position"] is not None:
        lo, hi = body_box(params, body)
        p = tuple(s["imu_position"])
        if not all(a - 1e-12 <= v <= b + 1e-12 for v, a, b in zip(p, lo, hi)):
            box = ", ".join(f"{c} in [{a:.4g}, {b:.4g}]" for c, a, b in zip("xyz", lo, hi))
            return (f"sensors.imu_position: ({', '.join(f'{v:g}' for v in p)}) m is outside the robot's body; allowed: "
                    f"a point of the body's box, {box} m (body frame, from the axle midpoint)")
    return None
