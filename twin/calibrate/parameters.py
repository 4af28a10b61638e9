"""The parameters ``twin calibrate`` can fit, with their units and where each lives.

One registry (:data:`PARAMETERS`): every name ``--parameters`` accepts, its SI unit, its group
(``plant``: Table III, :class:`twin.params.RobotParams`; ``motor``: the driver and motors,
:class:`twin.actuators.dc_motor.DCMotorParams`; ``imu``: the IMU's constants of the log;
``current``: the motor current sensor's, fitted whenever the log holds that channel), a
one-line description, and the fitted value's lower bound (the optimiser's box; physical
parameters are positive). Values are absolute SI values, as ``report.json`` writes them.

:data:`DEFAULT_PLANT` are fitted from any log; the yaw inertia ``n_zb`` only from a log that
turns, and the motors' figures only from a log with the applied duty (``duty.csv``), where
they are not confounded with the body's mass (research for issue 30: stall torque against the
mass/inertia scale, correlation 1.00 from N·m commands). A log with the motor current
(``motor_current.csv``) measures the torque itself: with it the motors' figures are fitted by
default (tests/test_motor_current_calibration.py).
"""
from __future__ import annotations

from dataclasses import dataclass

from twin.errors import TwinError


@dataclass(frozen=True)
class Parameter:
    """A fittable parameter: ``name``, ``unit`` (SI), ``group`` ("plant", "motor", "imu" or "current"),
    ``doc`` and ``lower`` (the smallest value the fit may take; None: unbounded)."""

    name: str
    unit: str
    group: str
    doc: str
    lower: float | None = 0.0


_ALL = (
    Parameter("m_b", "kg", "plant", "body mass"),
    Parameter("l", "m", "plant", "height of the body's centre of mass above the axle"),
    Parameter("n_yb", "kg·m²", "plant", "body inertia about the axle (pitch)"),
    Parameter("n_zb", "kg·m²", "plant", "body inertia about the vertical (yaw); needs a log that turns"),
    Parameter("d_b", "N·m·s/rad", "plant", "viscous resistance in the drive (body–wheel)"),
    Parameter("d_w", "N·m·s/rad", "plant", "viscous resistance wheel–ground"),
    Parameter("stall_torque", "N·m", "motor", "motor stall torque at the supply voltage; needs duty.csv"),
    Parameter("no_load_speed", "rad/s", "motor", "motor no-load speed at the supply voltage; needs duty.csv"),
    Parameter("dead_band", "1", "motor", "|duty| below which the driver gives no voltage; needs duty.csv"),
    Parameter("gyro_bias_x", "rad/s", "imu", "gyro bias, roll axis", None),
    Parameter("gyro_bias_y", "rad/s", "imu", "gyro bias, pitch axis", None),
    Parameter("gyro_bias_z", "rad/s", "imu", "gyro bias, yaw axis", None),
    Parameter("accel_bias_x", "m/s²", "imu", "accelerometer bias, forward axis", None),
    Parameter("gyro_scale_x", "1", "imu", "gyro scale-factor error, roll axis (the continuous model only: the roll "
              "gyro reads −α̇ sin θ while the robot turns leaning)", None),
    Parameter("gyro_scale_y", "1", "imu", "gyro scale-factor error, pitch axis (reading = (1 + s) × rate)", None),
    Parameter("gyro_scale_z", "1", "imu", "gyro scale-factor error, yaw axis", None),
    Parameter("accel_scale_x", "1", "imu", "accelerometer scale-factor error, forward axis", None),
    Parameter("accel_scale_z", "1", "imu", "accelerometer scale-factor error, vertical axis (its bias with it: "
              "the axis reads about g)", None),
    Parameter("imu_latency", "s", "imu", "the IMU's latency (whole control periods)"),
    Parameter("current_offset_l", "A", "current", "motor current sensor's offset, left wheel (fitted whenever the "
              "log holds the motor current)", None),
    Parameter("current_offset_r", "A", "current", "motor current sensor's offset, right wheel", None),
)
PARAMETERS: dict[str, Parameter] = {p.name: p for p in _ALL}
# parameters the model has but no log can show: `twin calibrate --list` leaves them out and says why
NOT_FROM_A_LOG = {"dead_band": "not fitted: a log's duty.csv holds the duty after the dead band, so the log cannot "
                               "show it; measure it on the bench (the smallest duty that turns the wheel)"}
DEFAULT_PLANT = ("m_b", "l", "n_yb", "d_b", "d_w")


def parse_names(text: str) -> tuple[str, ...]:
    """The names of ``--parameters NAMES`` (comma-separated, each once, in registry order), or
    a one-line :class:`~twin.errors.TwinError` naming what is wrong and what is allowed."""
    if not isinstance(text, str) or not text.strip():
        raise TwinError(f"--parameters needs at least one name; allowed: {', '.join(PARAMETERS)}")
    names = [n.strip() for n in text.split(",")]
    if "" in names:
        raise TwinError(f"--parameters {text!r} has an empty name; give names separated by commas, "
                        f"allowed: {', '.join(PARAMETERS)}")
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise TwinError(f"--parameters: no parameter {', '.join(repr(n) for n in unknown)}; "
                        f"allowed: {', '.join(PARAMETERS)}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise TwinError(f"--parameters names {', '.join(repr(n) for n in twice)} more than once")
    return tuple(n for n in PARAMETERS if n in names)
