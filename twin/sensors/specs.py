"""Sensor specifications: every default figure of the IMU and the encoders, in one place.

The IMU defaults are an MPU-6050-class part (InvenSense MPU-6000/6050 Product
Specification rev. 3.4, section 6.1–6.2), configured as balance bots use it:

=====================================  ===========================  =====================================
figure                                 gyro                         accelerometer
=====================================  ===========================  =====================================
full scale (FS_SEL / AFS_SEL = 0)      ±250 °/s                     ±2 g
ADC                                    16 bit (131 LSB per °/s)     16 bit (16384 LSB per g)
noise density (datasheet)              0.005 °/s/√Hz                400 µg/√Hz
sensitivity tolerance (datasheet ±3 %)  σ = 1 % (3σ = 3 %)          σ = 1 %
turn-on bias (see below)               σ = 0.5 °/s                  σ = 0 (calibrated)
bias random walk (see below)           4e-5 rad/s/√s                1e-4 m/s²/√s
output rate                            200 Hz (the control rate)    200 Hz
latency                                5 ms                         5 ms
=====================================  ===========================  =====================================

Judgement calls, documented rather than hidden:

* **Turn-on bias.** The datasheet's zero-rate output tolerance is ±20 °/s and its
  zero-g offset ±50 mg; every balance bot removes them by averaging at power-up (and
  the accelerometer once on a level surface), so what the twin draws at power-up is
  the residual: 0.5 °/s (1σ) for the gyro, which warm-up drift alone exceeds, and none
  for the accelerometer (set ``accel.turn_on_bias`` to study one: a residual of
  b m/s² tilts every accelerometer-aided estimate by b/g rad).
* **Bias random walk.** The datasheet gives no Allan figures; 4e-5 rad/s/√s and 1e-4
  m/s²/√s are typical of Allan-variance studies of consumer MEMS parts of this class
  (and of the figures used in visual-inertial configurations for them).
* **Latency.** The digital low-pass filter at DLPF_CFG = 3 (44 Hz bandwidth) delays the
  gyro by 4.8 ms and the accelerometer by 4.9 ms: one 5 ms control period.

Noise model (the one used by Gazebo, PX4 and Kalibr), per axis, at output interval Δt::

    y = (1 + s) x + b_on + b(t) + σ_w n,   σ_w = noise_density / √Δt,   n ~ N(0, 1)
    b(t+Δt) = b(t) + K √Δt n'                                    (random walk), or
    b(t+Δt) = e^{−Δt/τ} b(t) + K √(τ/2 (1 − e^{−2Δt/τ})) n'      (Gauss–Markov, τ given)

then clipped to the full scale and quantised to the ADC's two's-complement codes.

Encoders: an incremental quadrature encoder on each motor shaft (the motor drives the
wheel directly), 1200 counts per revolution (a 300-line disc, ×4 decoding), sampled at
the control rate. It counts from power-up, so it measures q_i − q_i(0) with q_i the
wheel's angle relative to the body (ψ_i − θ), not ψ_i.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from twin.errors import TwinError
from twin.validation import body_point, bounded_number

DEG = math.pi / 180.0
G0 = 9.80665  # m/s², the g of the datasheet's "g"


@dataclass(frozen=True)
class TriadSpec:
    """One 3-axis inertial sensor (gyro: rad/s; accelerometer: m/s²).

    Attributes
    ----------
    noise_density : unit/√Hz
        White noise; the per-sample σ is ``noise_density / √Δt``.
    bias_random_walk : unit/√s
        K: the bias wanders by K √Δt per sample (rate random walk for a gyro).
    bias_correlation_time : s or None
        None: the bias is a random walk; otherwise a first-order Gauss–Markov process
        with this time constant, driven by the same K (steady-state σ = K √(τ/2)).
    turn_on_bias : unit
        σ of the constant bias drawn once per run, per axis.
    scale_factor_error : 1
        σ of the per-axis sensitivity error s (y = (1 + s) x + ...).
    full_scale : unit
        Range ±full_scale; readings beyond it saturate.
    bits : int
        ADC resolution; LSB = full_scale / 2^(bits−1).
    """

    noise_density: float
    bias_random_walk: float
    bias_correlation_time: float | None
    turn_on_bias: float
    scale_factor_error: float
    full_scale: float
    bits: int = 16
    name: str = field(default="sensor", compare=False)

    def __post_init__(self):
        o = self.name
        for n, hi in (("noise_density", 1e3), ("bias_random_walk", 1e3), ("turn_on_bias", 1e3),
                      ("scale_factor_error", 0.5)):
            object.__setattr__(self, n, bounded_number(o, n, getattr(self, n), 0.0, hi, ""))
        if self.bias_correlation_time is not None:
            object.__setattr__(self, "bias_correlation_time",
                               bounded_number(o, "bias_correlation_time", self.bias_correlation_time, 0.0, 1e7, "s", True))
        object.__setattr__(self, "full_scale", bounded_number(o, "full_scale", self.full_scale, 0.0, 1e6, "", True))
        if not (isinstance(self.bits, int) and not isinstance(self.bits, bool) and 2 <= self.bits <= 32):
            raise TwinError(f"{o} bits must be an integer from 2 to 32, got {self.bits!r}")

    @property
    def lsb(self) -> float:
        """One ADC step, in the sensor's unit."""
        return self.full_scale / (1 << (self.bits - 1))

    def white_sigma(self, dt: float) -> float:
        """Per-sample σ of the white noise at output interval ``dt`` (s)."""
        return self.noise_density / math.sqrt(dt)


MPU6050_GYRO = TriadSpec(noise_density=0.005 * DEG, bias_random_walk=4e-5, bias_correlation_time=None,
                         turn_on_bias=0.5 * DEG, scale_factor_error=0.01, full_scale=250.0 * DEG, bits=16,
                         name="gyro")
MPU6050_ACCEL = TriadSpec(noise_density=400e-6 * G0, bias_random_walk=1e-4, bias_correlation_time=None,
                          turn_on_bias=0.0, scale_factor_error=0.01, full_scale=2.0 * G0, bits=16,
                          name="accelerometer")


@dataclass(frozen=True)
class ImuSpec:
    """The body's IMU: gyro and accelerometer, where it sits, how often and how late it reports.

    ``position`` (m) is the sensing point in the body frame relative to the axle
    midpoint: x forward, y left, z up along the body (the default is on the body's
    centre line, 10 cm above the axle, near the top of the nominal body). The axes
    are the body's. ``rate`` (Hz) must divide the control rate; ``latency`` (s) must be
    a whole number of control periods.
    """

    gyro: TriadSpec = MPU6050_GYRO
    accel: TriadSpec = MPU6050_ACCEL
    position: tuple[float, float, float] = (0.0, 0.0, 0.10)
    rate: float = 200.0
    latency: float = 0.005

    def __post_init__(self):
        if not isinstance(self.gyro, TriadSpec) or not isinstance(self.accel, TriadSpec):
            raise TwinError("imu gyro and accel must be TriadSpec instances")
        object.__setattr__(self, "position", body_point("imu position", self.position))
        object.__setattr__(self, "rate", bounded_number("imu", "rate", self.rate, 0.0, 1e5, "Hz", True))
        object.__setattr__(self, "latency", bounded_number("imu", "latency", self.latency, 0.0, 1.0, "s"))


@dataclass(frozen=True)
class EncoderSpec:
    """Incremental encoders on both motor shafts, read at the control rate.

    ``counts_per_rev``: quadrature counts per revolution; ``latency`` (s): a whole
    number of control periods (0: read at the control instant).
    """

    counts_per_rev: int = 1200
    latency: float = 0.0

    def __post_init__(self):
        c = self.counts_per_rev
        if not (isinstance(c, int) and not isinstance(c, bool) and 4 <= c <= 10_000_000):
            raise TwinError(f"encoder counts_per_rev must be an integer from 4 to 10000000, got {c!r}")
        object.__setattr__(self, "latency", bounded_number("encoder", "latency", self.latency, 0.0, 1.0, "s"))

    @property
    def resolution(self) -> float:
        """One count in rad."""
        return 2.0 * math.pi / self.counts_per_rev


DEFAULT_IMU = ImuSpec()
DEFAULT_ENCODERS = EncoderSpec()
