"""Sensor specifications: every figure of the IMU and the encoders, in one place.

Three IMU parts are modelled (:data:`IMU_PRESETS`, a scenario's ``sensors.imu``), each
configured as a balance bot would use it. The default is an MPU-6050-class part
(InvenSense MPU-6000/6050 Product Specification PS-MPU-6000A-00 rev. 3.4, sections
6.1–6.2 (gyroscope and accelerometer specifications)):

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

``icm42688p``: TDK InvenSense ICM-42688-P, Datasheet DS-000347 rev. 1.7, section 3.1
(Table 1, gyroscope specifications) and section 3.2 (Table 2, accelerometer
specifications; Tables 1–2 unchanged from rev. 1.2 to 1.8):

=====================================  ===========================  =====================================
figure                                 gyro                         accelerometer
=====================================  ===========================  =====================================
full scale (GYRO/ACCEL_FS_SEL = 2)     ±500 °/s                     ±4 g
ADC (UI registers)                     16 bit (65.5 LSB per °/s)    16 bit (8192 LSB per g)
noise density (datasheet)              0.0028 °/s/√Hz               70 µg/√Hz (z; x, y: 65)
sensitivity tolerance (datasheet)      ±0.5 % → σ = 0.167 %         ±0.5 % → σ = 0.167 %
zero offset drift (datasheet)          ±0.005 °/s/°C                ±0.15 mg/°C
turn-on bias (see below)               σ = 0.0156 °/s               σ = 0 (calibrated)
bias random walk (see below)           1.25e-6 rad/s/√s             3e-5 m/s²/√s
=====================================  ===========================  =====================================

``bmi088``: Bosch Sensortec BMI088, Data sheet BST-BMI088-DS001 rev. 1.3 (DS001-13, May
2018; rev. 1.9, BST-BMI088-DS000-19, Jan. 2024, has the same tables), section 1
(Specification): Table 4 (accelerometer, 1.2) and Table 5 (gyroscope, 1.3):

=====================================  ===========================  =====================================
figure                                 gyro                         accelerometer
=====================================  ===========================  =====================================
full scale (GYRO/ACC_RANGE = 2 / 1)    ±500 °/s                     ±6 g
ADC                                    16 bit (65.536 LSB per °/s)  16 bit (5460 LSB per g)
noise density (datasheet)              0.014 °/s/√Hz                190 µg/√Hz (z; x, y: 160; at ±3 g)
sensitivity tolerance                  ±1 % → σ = 0.333 %           ±1 % → σ = 0.333 % (see below)
zero offset drift (datasheet)          ±0.015 °/s/K                 < ±0.2 mg/K
bias stability (product flyer)         2 °/h                        —
turn-on bias (see below)               σ = 0.0469 °/s               σ = 0 (calibrated)
bias random walk (see below)           3.75e-6 rad/s/√s             4e-5 m/s²/√s
=====================================  ===========================  =====================================

Full scales. A balancing robot's pitch rate stays below ~3 rad/s (170 °/s) and the
specific force at its IMU below ~2 g, except in hard shoves and when it is picked up.
The MPU-6050 default keeps its most sensitive settings (±250 °/s, ±2 g); for the two
newer parts ±500 °/s and ±4 g / ±6 g (the BMI088's ranges are ±3/6/12/24 g) leave that
headroom while one LSB (0.015 °/s; 0.12 mg, 0.18 mg) stays below the white noise of one
200 Hz sample (0.040 and 0.198 °/s; 0.99 and 2.7 mg), so quantisation adds at most
1.3 % to the noise variance. The rate (``sensors.imu_rate``) and latency
(``sensors.imu_latency``) are the scenario's, not the part's: they follow from the
chosen output data rate and digital low-pass filter.

Judgement calls, documented rather than hidden:

* **Sensitivity tolerance.** A datasheet's ±tolerance is taken as 3σ of the per-axis
  scale-factor error. The BMI088 data sheet's accelerometer table gives no room-temperature
  sensitivity tolerance that we could confirm; the gyro's ±1 % is used for both.
* **Turn-on bias.** The MPU-6050's zero-rate output tolerance is ±20 °/s and its
  zero-g offset ±50 mg; every balance bot removes them by averaging at power-up (and
  the accelerometer once on a level surface), so what the twin draws at power-up is
  the residual: 0.5 °/s (1σ) for the gyro, which warm-up drift alone exceeds, and none
  for the accelerometer (set ``accel.turn_on_bias`` to study one: a residual of
  b m/s² tilts every accelerometer-aided estimate by b/g rad). The residual is a
  warm-up (temperature) drift, so for the other parts it is the MPU-6050's 0.5 °/s
  scaled by the ratio of the zero-rate drifts with temperature: the MPU-6050 drifts
  ±20 °/s over −40…+85 °C (0.16 °/s/K), the ICM-42688-P 0.005 °/s/K (× 1/32), the BMI088
  0.015 °/s/K (× 0.094).
* **Bias random walk.** No datasheet gives Allan figures; 4e-5 rad/s/√s and 1e-4
  m/s²/√s are typical of Allan-variance studies of consumer MEMS parts of the
  MPU-6050's class (and of the figures used in visual-inertial configurations for
  them). On a robot the slow bias wander is mostly temperature-driven, so the other
  parts' walks are the MPU-6050's scaled by the same drift ratios: gyro × 1/32 and
  × 0.094 as above; accelerometer by the zero-g drifts, 0.15 and 0.2 mg/K against the
  MPU-6050's ±35 mg over 0…70 °C (0.5 mg/K), × 0.3 and × 0.4. Check: the BMI088's gyro
  walk with its white noise puts the Allan minimum at √(2 N K / √3) = 6.7 °/h at
  τ = √3 N / K = 113 s, above the 2 °/h bias stability of Bosch's product flyer (not in
  the datasheet; measured at a constant temperature), as a robot's changing temperature
  should.
* **One noise density per triad.** The model draws every axis of a triad from one
  density; where a datasheet gives the z axis a larger one (ICM-42688-P 70 against
  65 µg/√Hz, BMI088 190 against 160 µg/√Hz) the preset takes the larger, so a filter
  tuned to it is never overconfident on an axis. The BMI088 specifies its accelerometer
  noise at ±3 g only; the ±6 g preset takes that figure.
* **Latency.** On the MPU-6050 the digital low-pass filter at DLPF_CFG = 3 (register map
  RM-MPU-6000A-00, section 4.3: accelerometer 44 Hz, gyro 42 Hz bandwidth) delays the
  gyro by 4.8 ms and the accelerometer by 4.9 ms: one 5 ms
  control period, the default ``sensors.imu_latency``.

Noise model (the one used by Gazebo, PX4 and Kalibr), per axis, at output interval Δt::

    y = (1 + s) x + b_on + b(t) + σ_w n,   σ_w = noise_density / √Δt,   n ~ N(0, 1)
    b(t+Δt) = b(t) + K √Δt n'                                    (random walk), or
    b(t+Δt) = e^{−Δt/τ} b(t) + K √(τ/2 (1 − e^{−2Δt/τ})) n'      (Gauss–Markov, τ given)

then clipped to the full scale and quantised to the ADC's two's-complement codes.

Range rule (:meth:`TriadSpec.range_problem`): a full scale must be at least
:data:`RANGE_NOISE_RATIO` (5) × the white noise of one sample at the IMU's rate,
noise_density·√rate, so that a sensor at rest does not saturate on its own noise (a
5σ excursion: probability 6e-7 per sample).

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
RANGE_NOISE_RATIO = 5.0  # a full scale is at least this many per-sample white-noise σ


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
    bias : (3,) unit or None
        The device's own constant bias, where known (a calibration's): every run has it
        instead of one drawn from ``turn_on_bias`` (the draw is still made: the other draws
        stay the same).
    scale : (3,) 1 or None
        Its scale-factor errors, where known, instead of draws from ``scale_factor_error``.
    name, unit : str
        For messages only: "gyro", "rad/s"; "accelerometer", "m/s²".
    """

    noise_density: float
    bias_random_walk: float
    bias_correlation_time: float | None
    turn_on_bias: float
    scale_factor_error: float
    full_scale: float
    bits: int = 16
    name: str = field(default="sensor", compare=False)
    unit: str = field(default="", compare=False)
    bias: tuple | None = None  # unit, x y z: the device's own constant bias, where known (instead of a draw)
    scale: tuple | None = None  # 1, x y z: its scale-factor errors, where known (instead of a draw)

    def __post_init__(self):
        o = self.name
        for n, hi in (("bias", 1e3), ("scale", 0.5)):
            v = getattr(self, n)
            if v is not None:
                if not (isinstance(v, (tuple, list)) and len(v) == 3):
                    raise TwinError(f"{o} {n} must be 3 numbers (x y z) or absent, got {v!r}")
                object.__setattr__(self, n, tuple(bounded_number(o, f"{n}[{i}]", x, -hi, hi, "")
                                                  for i, x in enumerate(v)))
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

    def range_problem(self, rate: float) -> str | None:
        """Why the full scale is too small for the noise at output ``rate`` (Hz), or None:
        it must be at least :data:`RANGE_NOISE_RATIO` × the per-sample white noise."""
        floor = RANGE_NOISE_RATIO * self.white_sigma(1.0 / rate)
        if self.full_scale >= floor:
            return None
        u = f" {self.unit}" if self.unit else ""
        return (f"{self.full_scale:.4g}{u} is below {RANGE_NOISE_RATIO:g} × the white noise of one sample "
                f"at the IMU rate ({RANGE_NOISE_RATIO:g} × noise_density·√({rate:g} Hz) = {floor:.4g}{u}): the "
                f"sensor would saturate on its own noise; allowed: full_scale ≥ {floor:.4g}{u} (or a lower "
                f"noise_density)")


def _gyro(**figures) -> TriadSpec:
    return TriadSpec(bias_correlation_time=None, bits=16, name="gyro", unit="rad/s", **figures)


def _accel(**figures) -> TriadSpec:
    return TriadSpec(bias_correlation_time=None, bits=16, name="accelerometer", unit="m/s²", **figures)


MPU6050_GYRO = _gyro(noise_density=0.005 * DEG, bias_random_walk=4e-5, turn_on_bias=0.5 * DEG,
                     scale_factor_error=0.01, full_scale=250.0 * DEG)
MPU6050_ACCEL = _accel(noise_density=400e-6 * G0, bias_random_walk=1e-4, turn_on_bias=0.0,
                       scale_factor_error=0.01, full_scale=2.0 * G0)
# ICM-42688-P and BMI088: drift-driven figures are the MPU-6050's scaled by the ratio of the
# offset drifts with temperature (see the module docstring): gyro 0.005 and 0.015 against
# 0.16 °/s/K, accelerometer 0.15 and 0.2 against 0.5 mg/K
ICM42688P_GYRO = _gyro(noise_density=0.0028 * DEG, bias_random_walk=4e-5 * 0.005 / 0.16,
                       turn_on_bias=0.5 * DEG * 0.005 / 0.16, scale_factor_error=0.005 / 3.0,
                       full_scale=500.0 * DEG)
ICM42688P_ACCEL = _accel(noise_density=70e-6 * G0, bias_random_walk=1e-4 * 0.15 / 0.5, turn_on_bias=0.0,
                         scale_factor_error=0.005 / 3.0, full_scale=4.0 * G0)
BMI088_GYRO = _gyro(noise_density=0.014 * DEG, bias_random_walk=4e-5 * 0.015 / 0.16,
                    turn_on_bias=0.5 * DEG * 0.015 / 0.16, scale_factor_error=0.01 / 3.0, full_scale=500.0 * DEG)
BMI088_ACCEL = _accel(noise_density=190e-6 * G0, bias_random_walk=1e-4 * 0.2 / 0.5, turn_on_bias=0.0,
                      scale_factor_error=0.01 / 3.0, full_scale=6.0 * G0)

IMU_PRESETS: dict[str, tuple[TriadSpec, TriadSpec]] = {
    "mpu6050": (MPU6050_GYRO, MPU6050_ACCEL),
    "icm42688p": (ICM42688P_GYRO, ICM42688P_ACCEL),
    "bmi088": (BMI088_GYRO, BMI088_ACCEL),
}
"""Preset name → (gyro, accelerometer) figures (the scenario key ``sensors.imu``)."""


@dataclass(frozen=True)
class ImuSpec:
    """The body's IMU: gyro and accelerometer, where it sits, how often and how late it reports.

    ``position`` (m) is the sensing point in the body frame relative to the axle
    midpoint: x forward, y left, z up along the body (the default is on the body's
    centre line, 10 cm above the axle, near the top of the nominal body). The axes
    are the body's unless ``orientation`` (rad: roll, pitch, yaw; the IMU's axes are the body's
    turned by yaw about z, then pitch about the new y, then roll about the newest x, as a sensor
    log's ``[imu] orientation``) says how it is mounted: its noise, biases, scale errors and
    range act along its own axes, and the readings are given in the body's axes (as a robot's
    firmware, or the log reader, turns them). ``rate`` (Hz) must divide the control rate; ``latency`` (s) must be
    a whole number of control periods.
    """

    gyro: TriadSpec = MPU6050_GYRO
    accel: TriadSpec = MPU6050_ACCEL
    position: tuple[float, float, float] = (0.0, 0.0, 0.10)
    rate: float = 200.0
    latency: float = 0.005
    orientation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # rad: roll, pitch, yaw of its axes in the body's

    def __post_init__(self):
        if not isinstance(self.gyro, TriadSpec) or not isinstance(self.accel, TriadSpec):
            raise TwinError("imu gyro and accel must be TriadSpec instances")
        object.__setattr__(self, "position", body_point("imu position", self.position))
        o = self.orientation
        if not (isinstance(o, (tuple, list)) and len(o) == 3):
            raise TwinError(f"imu orientation must be [roll, pitch, yaw] in rad, got {o!r}")
        object.__setattr__(self, "orientation", tuple(
            bounded_number("imu", f"orientation[{i}]", v, -b, b, "rad")
            for i, (v, b) in enumerate(zip(o, (math.pi, 0.5 * math.pi, math.pi)))))
        object.__setattr__(self, "rate", bounded_number("imu", "rate", self.rate, 0.0, 1e5, "Hz", True))
        object.__setattr__(self, "latency", bounded_number("imu", "latency", self.latency, 0.0, 1.0, "s"))
        for triad in (self.gyro, self.accel):
            problem = triad.range_problem(self.rate)
            if problem:
                raise TwinError(f"imu {triad.name} full_scale {problem}")


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


def preset_name(gyro: TriadSpec, accel: TriadSpec) -> str | None:
    """The name of the preset of :data:`IMU_PRESETS` whose figures these are, or None."""
    for name, (g, a) in IMU_PRESETS.items():
        if g == gyro and a == accel:
            return name
    return None
