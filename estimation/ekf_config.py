"""The EKF's numbers: every policy threshold in one table (:data:`POLICY`), and the typed
configuration (:class:`KernelConfig`) the compiled core is built from.

``POLICY``        a :class:`Policy`: the thresholds of the sensor front end's decisions (gates,
                  rails, stale samples, the latency watch, the encoders' checks, the physical
                  range, the restore), each defined here once; every module of the filter takes
                  them from here (the names in ``__all__`` are the same numbers, named)
``KernelConfig``  a frozen dataclass: what the compiled kernel ``estimation._ekf`` needs of the
                  model, the sensors and :data:`POLICY`, by name and with units
``c_header()``    the text of ``estimation/_ekf_config.h``, generated from :class:`KernelConfig`

One implementation of each policy. The compiled core fuses the whole IMU-driven step with its
decisions in C (one call per control period, ~7 µs against 150–260 µs in Python): calling the
Python rules from C would put the Python frames back into that step, so the rules that run
there (the accelerometer test, the IMU outlier test, the encoder gate, the truncation into an
unchanged count, the physical range, the restore) exist once in Python and once in C. What can
drift between the two is then the numbers and how they are handed over, and neither can:

* every threshold is defined once, in :data:`POLICY`; the C code holds no policy literal but
  reads each from the configuration it is built with (``c->tilt_limit``, ``c->gate[dof − 1]``);
* the configuration is :class:`KernelConfig`, read by the kernel *by field name*: the header
  ``estimation/_ekf_config.h`` is generated from the dataclass (``python -m
  estimation.ekf_config`` writes it), the kernel's ``Core`` struct and its table of names and
  offsets expand from it, ``new(config)`` reads each attribute by its name, and
  :class:`estimation.ekf_core.CompiledCore` refuses a kernel whose ``config_fields()`` differ
  from the dataclass's (a kernel built before a field was added or renamed);
* tests/test_ekf_layout.py fails if the header on disk is not the one the dataclass
  generates, if the built kernel's fields differ, or if a policy number is written in the C
  source; tests/test_estimator_kernel.py holds the two paths' decisions together, run by run.

The Python side has each decision rule in one place (:mod:`estimation.ekf_policies`,
:mod:`estimation.ekf_frontend`, :mod:`estimation.ekf_fusion`), the filter's arithmetic in
another (:mod:`estimation.ekf_filter`).

Nothing here imports more than the standard library.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path


@dataclass(frozen=True)
class Policy:
    """The EKF's policy thresholds (the module docstring of :mod:`estimation.ekf` gives the
    reasons and the measurements behind each)."""

    # the χ² gates: an IMU sample is called an outlier only on much stronger evidence than an
    # encoder sample (wrongly replacing a real sample by the model's is worse than keeping a
    # mild outlier): probability (1) that the IMU gate rejects a sample that fits
    imu_gate_probability: float = 1e-9
    # the accelerometer test: its innovation less the median of the last three must pass the
    # IMU gate at this many times its variance (1) ...
    accel_variance_factor: float = 2.0
    # ... and at most this many samples in a row are rejected before the next is taken as real
    accel_max_in_row: int = 2
    # the gyro's variance against the model's rate: its noise in this sample and in the two
    # the model's θ̇ is extrapolated from, 1 + 1.5² + 0.5² samples' worth (1)
    gyro_extrapolation_samples: float = 3.5
    # counts each side added to the count an unchanged wheel is kept in (KeepInside)
    inside_margin: float = 1.0
    # m/s: encoder counts implying a faster wheel (relative to the body) are a fault
    max_rim_speed: float = 20.0
    # counts: a reading beyond ± this many counts is beyond a 32-bit counter's range
    counter_range: float = float(2 ** 31)
    # white-noise σ from the end of its range within which an IMU reading is censored, not a
    # measurement (its noise is cut by the rail)
    rail_sigmas: float = 3.0
    # ADC steps of white noise per sample from which a repeated triad is stale, not measured
    # (three axes then repeat by chance with probability < 4e-4)
    stale_lsb: float = 4.0
    # the physical range of the state: |θ| below this (rad) ...
    tilt_limit: float = 0.5 * math.pi
    # ... θ's variance below that of a tilt known only to lie in (−π/2, π/2), uniform (rad²) ...
    tilt_var_max: float = math.pi * math.pi / 12.0
    # ... and the heading's variance capped at a uniform angle's on the circle (rad²)
    heading_var_max: float = math.pi * math.pi / 3.0
    # s without an encoder sample after which the position is reported as degraded
    encoders_lost_after: float = 1.0
    # variance of U(−½, ½): where ∫v lies in Δt [v, v⁺] about the trapezoid's midpoint (1)
    trapezoid_var: float = 1.0 / 12.0
    # a restored last good state's covariance: this times P (1) ...
    restore_inflation: float = 4.0
    # ... plus this on its diagonal (the states' units squared)
    restore_jitter: float = 1e-10
    # s: the consider states are held from learn_time less this (the instants' float times)
    learn_slack: float = 1e-9
    # the latency watch (LatencyWatch), in control periods but for the two correlations:
    watch_window: int = 100  # samples correlated (0.5 s at 200 Hz)
    watch_every: int = 10  # periods between checks
    watch_max_lag: int = 20  # the largest latency looked for (100 ms at 200 Hz)
    watch_rho: float = 0.2  # the best lag's correlation (1) must reach this ...
    watch_margin: float = 0.15  # ... and beat the assumed latency's by this much ...
    watch_persist: int = 3  # ... in this many checks in a row
    watch_clip: float = 5.0  # robust σ of the window's Δ²ω_y beyond which a row is winsorised


POLICY = Policy()

# the same numbers by the names the filter's modules and the tests use
IMU_GATE_PROBABILITY = POLICY.imu_gate_probability
ACCEL_VARIANCE_FACTOR = POLICY.accel_variance_factor
ACCEL_MAX_IN_ROW = POLICY.accel_max_in_row
GYRO_EXTRAPOLATION_SAMPLES = POLICY.gyro_extrapolation_samples
INSIDE_MARGIN = POLICY.inside_margin
MAX_RIM_SPEED = POLICY.max_rim_speed
COUNTER_RANGE = POLICY.counter_range
RAIL_SIGMAS = POLICY.rail_sigmas
STALE_LSB = POLICY.stale_lsb
TILT_LIMIT = POLICY.tilt_limit
TILT_VAR_MAX = POLICY.tilt_var_max
HEADING_VAR_MAX = POLICY.heading_var_max
ENCODERS_LOST_AFTER = POLICY.encoders_lost_after
TRAPEZOID_VAR = POLICY.trapezoid_var
RESTORE_INFLATION = POLICY.restore_inflation
RESTORE_JITTER = POLICY.restore_jitter
LEARN_SLACK = POLICY.learn_slack
WATCH_WINDOW = POLICY.watch_window
WATCH_EVERY = POLICY.watch_every
WATCH_MAX_LAG = POLICY.watch_max_lag
WATCH_RHO = POLICY.watch_rho
WATCH_MARGIN = POLICY.watch_margin
WATCH_PERSIST = POLICY.watch_persist
WATCH_CLIP = POLICY.watch_clip


def _c(doc: str, n: int = 1, default=None):
    """A :class:`KernelConfig` field: ``doc`` its meaning with its unit (the generated header's
    comment too), ``n`` its length in the kernel (1: a scalar, else a tuple of n floats)."""
    meta = {"doc": doc, "n": n}
    return field(metadata=meta) if default is None else field(default=default, metadata=meta)


@dataclass(frozen=True)
class KernelConfig:
    """What the compiled kernel (``estimation._ekf``) is built from, each number by its name.

    The kernel reads every field by name into a C double (a tuple of n: an array of n), in
    the order of ``estimation/_ekf_config.h``, which :func:`c_header` generates from these
    fields; booleans and counts are read as 0.0/1.0 and whole numbers. The policy fields
    default to :data:`POLICY`'s."""

    # the filter
    dt: float = _c("s: the filter's step, imu_every control periods")
    r: float = _c("m: the wheels' radius")
    xi: float = _c("m: the IMU's forward position in the body frame")
    zi: float = _c("m: the IMU's height above the axle in the body frame")
    b_r: float = _c("1: half the track over the wheels' radius, b / r")
    alpha0: float = _c("rad: the heading the encoders' odometry starts from")
    delta: float = _c("rad: one encoder count")
    g_var: float = _c("(rad/s)^2: the gyro's noise per sample (white noise and ADC step)")
    a_var: float = _c("(m/s^2)^2: the accelerometer's noise per sample (white noise and ADC step)")
    bias_q: float = _c("(rad/s)^2: the gyro bias's random-walk variance over one step")
    gate: tuple = _c("1: the encoder update's chi-square gate for 1 and 2 degrees of freedom", 2)
    imu_gate: tuple = _c("1: the IMU outlier test's chi-square gate for 1 and 2 degrees of freedom", 2)
    lim: tuple = _c("the ADC's full scale: omega_y, omega_z (rad/s), f_x, f_z (m/s^2)", 4)
    # the estimator's model: equation (1) with d_b + c_e, and the motors' driver
    mdt: float = _c("s: the model's step, one control period")
    m11: float = _c("kg m^2: equation (1)'s inertia term m11")
    m12: float = _c("kg m^2: equation (1)'s inertia term m12 (per cos theta)")
    m22: float = _c("kg m^2: equation (1)'s inertia term m22")
    n_bla: float = _c("kg m^2: the yaw-pitch inertia coupling of equation (1)")
    d_b: float = _c("N m s/rad: the body-wheel damping, the motors' back-EMF slope included")
    d_w: float = _c("N m s/rad: the wheel-ground damping")
    g_b: float = _c("N m: the gravity torque of equation (1) per sin theta")
    yaw_damping: float = _c("N m s/rad: the yaw's damping")
    m33: float = _c("kg m^2: the yaw inertia upright")
    g: float = _c("m/s^2: the acceleration of gravity")
    has_motor: bool = _c("0/1: the motors' driver is modelled (else ideal torque sources)")
    compensates: bool = _c("0/1: the driver compensates the back-EMF")
    tau_max: float = _c("N m: the stall torque a wheel's command is clipped to")
    i_tau: float = _c("N m: the current limit's torque")
    sigma_tau: float = _c("N m: the PWM step's torque sigma")
    c_e: float = _c("N m s/rad: the back-EMF slope")
    tol: float = _c("1: the delivered torque's sigma relative to the command")
    every: int = _c("control periods per IMU sample")
    max_rejects_in_row: int = _c("encoder samples rejected in a row after which the next is forced in")
    inside_half: float = _c("rad: half the width of the interval an unchanged count keeps its wheel in")
    stuck_sigmas: float = _c("1: sigma outside that interval at which an unchanged count is implausible")
    msub: int = _c("the model's RK4 steps per control period")
    # the policy (POLICY's numbers)
    tilt_limit: float = _c("rad: the physical range's largest |theta|", default=POLICY.tilt_limit)
    tilt_var_max: float = _c("rad^2: the physical range's largest variance of theta", default=POLICY.tilt_var_max)
    trapezoid_var: float = _c("1: the trapezoid's error in psi, in (dt |v1 - v| / r)^2",
                              default=POLICY.trapezoid_var)
    gyro_extrapolation_samples: float = _c("1: the gyro's samples of noise in its innovation against the model",
                                           default=POLICY.gyro_extrapolation_samples)
    accel_variance_factor: float = _c("1: the accelerometer test's variance factor",
                                      default=POLICY.accel_variance_factor)
    restore_inflation: float = _c("1: a restored state's covariance, times P", default=POLICY.restore_inflation)
    restore_jitter: float = _c("a restored state's covariance, plus this on the diagonal",
                               default=POLICY.restore_jitter)

    def __post_init__(self):
        for f in fields(self):
            n = f.metadata["n"]
            v = getattr(self, f.name)
            if n > 1 and (not isinstance(v, tuple) or len(v) != n):
                raise ValueError(f"KernelConfig.{f.name} must be a tuple of {n} numbers, got {v!r}")


CONFIG_FIELDS = tuple(f.name for f in fields(KernelConfig))
HEADER = Path(__file__).with_name("_ekf_config.h")


def c_header() -> str:
    """The text of ``estimation/_ekf_config.h``: the X-macro ``EKF_CONFIG(S, A)`` that lists
    :class:`KernelConfig`'s fields in order, ``S(name)`` a scalar and ``A(name, n)`` an array."""
    lines = ["/* Generated from estimation/ekf_config.py (KernelConfig) by `python -m estimation.ekf_config`:",
             "   do not edit. The compiled EKF's configuration, read by field name (estimation/_ekf.c). */",
             "#ifndef EKF_CONFIG_H", "#define EKF_CONFIG_H", "",
             f"#define EKF_CONFIG_COUNT {len(CONFIG_FIELDS)}", "", "#define EKF_CONFIG(S, A) \\"]
    for f in fields(KernelConfig):
        n = f.metadata["n"]
        item = f"S({f.name})" if n == 1 else f"A({f.name}, {n})"
        lines.append(f"    {item:34s}/* {f.metadata['doc']} */ \\")
    lines[-1] = lines[-1][:-2].rstrip()
    lines += ["", "#endif", ""]
    return "\n".join(lines)


def write_header() -> Path:
    """Write :func:`c_header` to ``estimation/_ekf_config.h``."""
    HEADER.write_text(c_header(), encoding="utf-8")
    return HEADER


__all__ = ["ACCEL_MAX_IN_ROW", "ACCEL_VARIANCE_FACTOR", "CONFIG_FIELDS", "COUNTER_RANGE", "ENCODERS_LOST_AFTER",
           "GYRO_EXTRAPOLATION_SAMPLES", "HEADING_VAR_MAX", "IMU_GATE_PROBABILITY", "INSIDE_MARGIN", "KernelConfig",
           "LEARN_SLACK", "MAX_RIM_SPEED", "POLICY", "Policy", "RAIL_SIGMAS", "RESTORE_INFLATION", "RESTORE_JITTER",
           "STALE_LSB", "TILT_LIMIT", "TILT_VAR_MAX", "TRAPEZOID_VAR", "WATCH_CLIP", "WATCH_EVERY", "WATCH_MARGIN",
           "WATCH_MAX_LAG", "WATCH_PERSIST", "WATCH_RHO", "WATCH_WINDOW", "c_header", "write_header"]

if __name__ == "__main__":
    print(write_header())
