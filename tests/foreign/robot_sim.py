"""An independent simulator of a mobile two-wheeled inverted pendulum that writes sensor logs
in the twin's format: data the twin did not write (issue 40).

Nothing here comes from ``twin`` or ``estimation``: only the standard library, numpy and
scipy. The plant is equation (1) of the project's paper notes, integrated by classical RK4
at 1 kHz; the controller, its estimator, the IMU, the encoders, the log writer and the
axes' conventions are this module's own, written from the notes and the log format's
documentation (``docs/howto/robot-logs.md``), so that an error shared by the twin's stepping
or sensors and its estimators does not cancel out here.

Plant (equation (1), all three equations, yaw coupling included)::

    m11 ψ̈ + m12 cosθ θ̈ = m12 (θ̇² + α̇²) sinθ − 2 d_w ψ̇ + 2 d_b (θ̇ − ψ̇) + u_r + u_l + F r
    m12 cosθ ψ̈ + m22 θ̈ = n_bla α̇² sinθ cosθ + g_b sinθ − 2 d_b (θ̇ − ψ̇) − u_r − u_l + F l cosθ
    J(θ) α̈ = −2 n_bla α̇ θ̇ sinθ cosθ − m12 α̇ ψ̇ sinθ − (2b²/r²)(d_b + d_w) α̇ + (b/r)(u_r − u_l)

with m11 = (m_b + 2 m_w) r² + 2 n_wa, m12 = m_b l r, m22 = m_b l² + n_yb, g_b = m_b g l,
J(θ) = m33 + n_bla sin²θ, m33 = n_zb + 2 n_wd + (2b²/r²)(n_wa + m_w r²),
n_bla = m_b l² + n_xb − n_zb, n_xb = n_yb (the notes' choice; the source lists no n_xb).
F is a push (N) at the body's centre of mass along the heading: its generalised forces
follow from the virtual work F δx_c with x_c = r ψ + l sinθ, i.e. F r on ψ and F l cosθ on
θ (τ1 and τ2 of the notes); it exerts no yaw moment. Without damping and inputs the energy
E = ½ (m11 ψ̇² + 2 m12 cosθ ψ̇ θ̇ + m22 θ̇²) + ½ J(θ) α̇² + g_b cosθ is conserved (the
nonholonomic terms m12 α̇² sinθ and −m12 α̇ ψ̇ sinθ do no work together), which
:func:`energy` gives and the fixture's test checks.

Conventions (those of the log format): x forward, y along the axle to the left, z up the
body; θ > 0 leans forward (a positive rotation about +y), ψ > 0 rolls forward, α > 0 turns
left (about +z); ψ = (ψ_l + ψ_r)/2 and ψ_r − ψ_l = (2b/r)(α − α_0); an encoder counts its
wheel's angle relative to the body, q_j = ψ_j − θ, forward positive.

Sensors (:class:`ImuModel`): the body's angular velocity in body axes is
ω = (−α̇ sinθ, θ̇, α̇ cosθ); the IMU at p (body axes, from the axle midpoint) feels the
specific force f = a_P − g_world, a_P = a_O + ω̇ × p + ω × (ω × p) with the axle midpoint's
acceleration a_O = (r ψ̈ cosθ, r ψ̇ α̇, r ψ̈ sinθ) in body axes (rolling without slip) and
ω̇ the time derivative of ω's body components (the angular acceleration, in body axes);
gravity's part is g (−sinθ, 0, cosθ), so at rest upright the accelerometer reads +g on z.
An IMU mounted pitched by β (a rotation about the axle) reads R_y(β)ᵀ v for a body-axes
vector v: upright at rest it reads (−g sin β, 0, g cos β). Each sample is either the mean
over its interval (the ideal delta-angle/delta-velocity of the interval, integrated with the
RK4 stages' weights, exact to the integrator's order) or a point sample at its instant; then
reading = (1 + s) ⊙ true + bias + white noise (+ vibration noise), clipped to the range and
quantised to the ADC's two's-complement codes, and delivered ``latency`` s later.

Profiles (:func:`profile_a`, :func:`profile_b`; issue 40's two kinds of outside data):

* **A**, the "independent simulator": 200 Hz control and logging, an MPU-6050-like IMU
  (datasheet densities, constant biases, 1 % scale factors or none, ±250 °/s and ±2 g),
  5 ms interval means delivered 5 ms late, 1440-count encoders, ideal torque sources, a
  true plant of m_b × 1.15, l × 0.9, d_b and d_w × 1.5 against Table III, drives, turns and
  half-sine pushes; variants ``clip`` (a sharper catch from 0.35–0.45 rad that clips the
  gyro and the accelerometer) and ``push`` (10–12 N pushes).
* **B**, a real-robot-shaped log: a 0.8 kg robot on 30 mm wheels (radius), 12 V gear
  motors driven by voltages, an inner loop at 1 kHz logged one row every 30–33 ms
  (jittered), the commanded voltage *sampled* at the logged instant, an IMU pitched
  0.07 rad, ±2 g, vibration noise, starting from lying at about 0.5 rad and caught.

:func:`write_log` writes version 1 of the sensor-log format (the default) or version 2 with its
own CSV writer, the state truth included; what version 1 cannot say (sampling, mounting angle,
sampled voltage commands, vibration noise) version 2 says in log.toml, and the sidecar
``robot_sim.json`` holds the rest (the true plant, the drawn constants).
Everything is determined by the seed (one ``numpy.random.default_rng(seed)``, split into
independent streams).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

GRAVITY = 9.81  # m/s², the g of the plant (g_b = m_b g l)
DEG = math.pi / 180.0
G0 = 9.80665  # m/s², the datasheet's "g" (accelerometer ranges and µg densities)
FORMAT_VERSION = 1  # the sensor-log format version written by default (write_log(version=2) writes version 2)
GENERATOR = "tests/foreign/robot_sim.py"


# ---- the plant -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlantParams:
    """True physical parameters (SI). Defaults: the paper's Table III."""

    m_w: float = 0.14  # kg, each wheel
    m_b: float = 2.58  # kg, body
    n_wa: float = 0.00014  # kg·m², wheel about its axle
    n_wd: float = 0.00054  # kg·m², wheel about a diameter
    n_yb: float = 0.00128  # kg·m², body about the axle (pitch)
    n_zb: float = 0.00128  # kg·m², body about the vertical (yaw)
    r: float = 0.04  # m, wheel radius
    b: float = 0.15  # m, half the wheel distance
    l: float = 0.0622  # m, axle to the body's centre of mass
    d_b: float = 0.001  # N·m·s/rad, viscous resistance body–wheel (the drive)
    d_w: float = 0.01  # N·m·s/rad, viscous resistance wheel–ground
    g: float = GRAVITY  # m/s²
    n_xb: float | None = None  # kg·m², body about the roll axis; None: n_yb (the notes' choice)

    @property
    def roll_inertia(self) -> float:
        """n_xb in kg·m² (n_yb unless given)."""
        return self.n_yb if self.n_xb is None else self.n_xb

    def scaled(self, **factors: float) -> "PlantParams":
        """This plant with parameters multiplied by ``factors`` (name → factor); a defaulted n_xb
        follows n_yb."""
        unknown = set(factors) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(f"unknown plant parameter(s): {sorted(unknown)}")
        return replace(self, **{k: getattr(self, k) * float(v) for k, v in factors.items()})

    def derived(self) -> dict:
        """m11, m12, m22 (kg·m², kg·m·m), g_b (N·m), m33 and n_bla (kg·m²) of the notes."""
        r, b = self.r, self.b
        return {"m11": (self.m_b + 2.0 * self.m_w) * r * r + 2.0 * self.n_wa,
                "m12": self.m_b * self.l * r,
                "m22": self.m_b * self.l * self.l + self.n_yb,
                "g_b": self.m_b * self.g * self.l,
                "m33": self.n_zb + 2.0 * self.n_wd + (2.0 * b * b / (r * r)) * (self.n_wa + self.m_w * r * r),
                "n_bla": self.m_b * self.l * self.l + self.roll_inertia - self.n_zb}


TABLE_III = PlantParams()


@dataclass(frozen=True)
class MotorParams:
    """A brushed DC gear motor per wheel, driven by a voltage, inductance neglected.

    Wheel torque τ = k (V − k ω) / R with k = gear × k_t (k_t = k_e, N·m/A = V·s/rad) and ω the
    wheel's speed relative to the body (ψ̇_j − θ̇), rad/s; V clipped to ±supply."""

    resistance: float = 7.5  # Ω
    k_t: float = 0.343 / 30.0  # N·m/A at the motor shaft (= k_e in V·s/rad)
    gear: float = 30.0  # motor turns per wheel turn
    supply: float = 12.0  # V

    @property
    def k(self) -> float:
        """N·m/A (= V·s/rad) at the wheel: gear × k_t."""
        return self.gear * self.k_t

    @property
    def stall_torque(self) -> float:
        """N·m at the wheel at the supply voltage, standing."""
        return self.k * self.supply / self.resistance

    @property
    def no_load_speed(self) -> float:
        """rad/s of the wheel relative to the body at the supply voltage, unloaded."""
        return self.supply / self.k

    def torque(self, volts: float, omega: float) -> float:
        """N·m on the wheel for ``volts`` (V) at relative speed ``omega`` (rad/s)."""
        return self.k * (volts - self.k * omega) / self.resistance


class Dynamics:
    """Equation (1) for one plant (and its motors, if any): :meth:`accelerations` and the RK4
    :meth:`step`. State s = (θ, θ̇, ψ, ψ̇, α, α̇) in rad and rad/s. Inputs are the wheel torques
    (N·m, ideal torque sources) or, with ``motor``, the motor voltages (V)."""

    def __init__(self, plant: PlantParams, motor: MotorParams | None = None, imu_position=(0.0, 0.0, 0.1)):
        d = plant.derived()
        self.plant, self.motor = plant, motor
        self.m11, self.m12, self.m22, self.g_b = d["m11"], d["m12"], d["m22"], d["g_b"]
        self.m33, self.n_bla = d["m33"], d["n_bla"]
        self.r, self.l, self.g = plant.r, plant.l, plant.g
        self.bor = plant.b / plant.r
        self.d_b, self.d_w = plant.d_b, plant.d_w
        self.yaw_damping = 2.0 * self.bor * self.bor * (plant.d_b + plant.d_w)  # N·m·s/rad on α̇
        self.p = tuple(float(v) for v in imu_position)

    def torques(self, s, in_l: float, in_r: float) -> tuple[float, float]:
        """(τ_l, τ_r) N·m from the inputs at state s: the inputs themselves, or the motors' torque."""
        if self.motor is None:
            return in_l, in_r
        m = self.motor
        w = s[3] - s[1]  # ψ̇ − θ̇: the mean wheel's speed relative to the body
        dw = self.bor * s[5]  # half the wheels' speed difference, (b/r) α̇
        vs = m.supply
        vl, vr = min(vs, max(-vs, in_l)), min(vs, max(-vs, in_r))
        return m.torque(vl, w - dw), m.torque(vr, w + dw)

    def accelerations(self, s, in_l: float, in_r: float, force: float = 0.0) -> tuple[float, float, float]:
        """(θ̈, ψ̈, α̈) at state s with inputs (in_l, in_r) and a push ``force`` (N)."""
        th, thd, _, psd, _, ald = s
        tl, tr = self.torques(s, in_l, in_r)
        sn, cs = math.sin(th), math.cos(th)
        u = tl + tr
        drive = 2.0 * self.d_b * (thd - psd)
        r1 = self.m12 * (thd * thd + ald * ald) * sn - 2.0 * self.d_w * psd + drive + u + force * self.r
        r2 = self.n_bla * ald * ald * sn * cs + self.g_b * sn - drive - u + force * self.l * cs
        c12 = self.m12 * cs
        det = self.m11 * self.m22 - c12 * c12
        psdd = (self.m22 * r1 - c12 * r2) / det
        thdd = (self.m11 * r2 - c12 * r1) / det
        J = self.m33 + self.n_bla * sn * sn
        aldd = (-2.0 * self.n_bla * ald * thd * sn * cs - self.m12 * ald * psd * sn - self.yaw_damping * ald
                + self.bor * (tr - tl)) / J
        return thdd, psdd, aldd

    def imu_true(self, s, acc) -> tuple:
        """(specific force (3,) m/s², angular velocity (3,) rad/s), both in body axes, at the IMU's
        point for state s and accelerations ``acc`` = (θ̈, ψ̈, α̈) (see the module docstring)."""
        th, thd, _, psd, _, ald = s
        thdd, psdd, aldd = acc
        sn, cs = math.sin(th), math.cos(th)
        wx, wy, wz = -ald * sn, thd, ald * cs
        ex, ey, ez = -aldd * sn - ald * thd * cs, thdd, aldd * cs - ald * thd * sn  # dω/dt, body components
        px, py, pz = self.p
        r = self.r
        # ω × p, then ω × (ω × p) and ω̇ × p
        cx, cy, cz = wy * pz - wz * py, wz * px - wx * pz, wx * py - wy * px
        ax = r * psdd * cs + (ey * pz - ez * py) + (wy * cz - wz * cy) - self.g * sn
        ay = r * psd * ald + (ez * px - ex * pz) + (wz * cx - wx * cz)
        az = r * psdd * sn + (ex * py - ey * px) + (wx * cy - wy * cx) + self.g * cs
        return (ax, ay, az), (wx, wy, wz)

    def derivative(self, s, in_l, in_r, force):
        """(ds/dt (6,), outputs (6,): specific force and angular velocity in body axes)."""
        acc = self.accelerations(s, in_l, in_r, force)
        f, w = self.imu_true(s, acc)
        return (s[1], acc[0], s[3], acc[1], s[5], acc[2]), f + w

    def step(self, s, h: float, in_l: float, in_r: float, push=None, t: float = 0.0):
        """One classical RK4 step of ``h`` s from state s at time ``t`` with the inputs held;
        ``push(t)`` the push force (N) at time t (None: none). Returns (the new state, the
        integral over the step of the IMU's true outputs (6,) by the same RK4 weights: the
        quadrature of the interval means)."""
        F0 = push(t) if push else 0.0
        Fm = push(t + 0.5 * h) if push else 0.0
        F1 = push(t + h) if push else 0.0
        k1, y1 = self.derivative(s, in_l, in_r, F0)
        s2 = tuple(a + 0.5 * h * b for a, b in zip(s, k1))
        k2, y2 = self.derivative(s2, in_l, in_r, Fm)
        s3 = tuple(a + 0.5 * h * b for a, b in zip(s, k2))
        k3, y3 = self.derivative(s3, in_l, in_r, Fm)
        s4 = tuple(a + h * b for a, b in zip(s, k3))
        k4, y4 = self.derivative(s4, in_l, in_r, F1)
        h6 = h / 6.0
        new = tuple(a + h6 * (p + 2.0 * q + 2.0 * w + z) for a, p, q, w, z in zip(s, k1, k2, k3, k4))
        quad = tuple(h6 * (p + 2.0 * q + 2.0 * w + z) for p, q, w, z in zip(y1, y2, y3, y4))
        return new, quad


def energy(plant: PlantParams, s) -> float:
    """Mechanical energy (J) of state s (kinetic + the body's potential energy m_b g l cosθ)."""
    d = plant.derived()
    th, thd, _, psd, _, ald = s
    J = d["m33"] + d["n_bla"] * math.sin(th) ** 2
    return (0.5 * (d["m11"] * psd * psd + 2.0 * d["m12"] * math.cos(th) * psd * thd + d["m22"] * thd * thd)
            + 0.5 * J * ald * ald + d["g_b"] * math.cos(th))


def linearise(plant: PlantParams, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(A (4, 4), B (4, 1)) of the balance model at upright rest, x = [θ, θ̇, ψ, ψ̇], u = u_l + u_r
    (N·m): central differences of :meth:`Dynamics.accelerations` (the very equations integrated),
    with the torque split equally between the wheels."""
    dyn = Dynamics(plant)

    def f(x, u):
        s = (x[0], x[1], x[2], x[3], 0.0, 0.0)
        thdd, psdd, _ = dyn.accelerations(s, 0.5 * u, 0.5 * u)
        return np.array([x[1], thdd, x[3], psdd])

    A = np.zeros((4, 4))
    for j in range(4):
        e = np.zeros(4)
        e[j] = eps
        A[:, j] = (f(e, 0.0) - f(-e, 0.0)) / (2.0 * eps)
    B = ((f(np.zeros(4), eps) - f(np.zeros(4), -eps)) / (2.0 * eps)).reshape(4, 1)
    return A, B


# ---- sensors -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImuModel:
    """An MPU-6050-like IMU (defaults: the datasheet's figures at FS_SEL = AFS_SEL = 0).

    reading = quantise(clip((1 + s) ⊙ true + bias + white + vibration)), per axis, in the IMU's
    axes (the body's rotated by ``mount_pitch`` about the axle)."""

    rate: float = 200.0  # Hz, samples per second
    latency: float = 0.005  # s from a sample's instant to its delivery
    sampling: str = "mean"  # "mean" over the sample interval, or "point" at the instant
    position: tuple = (0.0, 0.0, 0.1)  # m, body axes from the axle midpoint
    mount_pitch: float = 0.0  # rad, the IMU's axes rotated about the axle from the body's
    gyro_density: float = 0.005 * DEG  # rad/s/√Hz (datasheet 0.005 °/s/√Hz)
    accel_density: float = 400e-6 * G0  # m/s²/√Hz (datasheet 400 µg/√Hz)
    gyro_bias_sigma: float = 0.5 * DEG  # rad/s, 1σ of the constant bias per axis (residual after power-up averaging)
    accel_bias_sigma: float = 0.005  # m/s², 1σ of the constant bias per axis (residual after a level calibration)
    scale_sigma: float = 0.01  # 1σ of each axis's scale-factor error (gyro and accelerometer); 0: none
    gyro_range: float = 250.0 * DEG  # rad/s, ±full scale
    accel_range: float = 2.0 * G0  # m/s², ±full scale
    bits: int = 16  # ADC resolution
    vibration_gyro: float = 0.0  # rad/s, σ of a white vibration noise per sample
    vibration_accel: float = 0.0  # m/s², σ of a white vibration noise per sample

    def white_sigma(self) -> tuple[float, float]:
        """Per-sample σ of the white noise (gyro rad/s, accel m/s²): density × √rate (for a mean
        over 1/rate s, and for a point sample whose bandwidth is matched to the rate)."""
        q = math.sqrt(self.rate)
        return self.gyro_density * q, self.accel_density * q


@dataclass(frozen=True)
class Push:
    """A half-sine push at the body's centre of mass along the heading: peak ``force`` N (forward
    positive) from ``start`` s for ``duration`` s."""

    start: float
    duration: float
    force: float

    def at(self, t: float) -> float:
        x = (t - self.start) / self.duration
        return self.force * math.sin(math.pi * x) if 0.0 <= x <= 1.0 else 0.0


@dataclass(frozen=True)
class Target:
    """From ``time`` s on, go to ``position`` m (distance travelled, r ψ) and turn to ``heading`` rad
    (None: keep the previous one)."""

    time: float
    position: float | None = None
    heading: float | None = None


@dataclass(frozen=True)
class ControllerSpec:
    """The generator's own controller: a continuous LQR on the linearised balance model of the
    *nominal* plant (x = [θ, θ̇, ψ − ψ_d, ψ̇ − ψ̇_d], Q = diag(1/x_max²), R = 1/u_max²), a heading
    PD on the torque difference, references ramped with speed and acceleration limits."""

    rate: float = 200.0  # Hz
    theta_max: float = 0.05  # rad: Bryson's rule scales of the LQR's Q and R
    theta_dot_max: float = 5.0  # rad/s
    position_max: float = 0.1  # m
    speed_max: float = 0.5  # m/s
    torque_max: float = 0.1  # N·m, total (R's scale)
    torque_limit: float = 2.0  # N·m per wheel: commands are clipped to it (ideal sources)
    position_error_limit: float = 0.2  # m: the LQR's position error is clipped to ±this
    heading_bandwidth: float = 5.0  # rad/s, natural frequency of the heading loop (critically damped)
    drive_speed: float = 0.3  # m/s, the position reference's speed limit
    drive_accel: float = 0.6  # m/s², its acceleration limit
    turn_rate: float = 1.0  # rad/s, the heading reference's rate limit
    turn_accel: float = 3.0  # rad/s², its acceleration limit
    filter_gain: float = 1.0  # 1/s, the complementary filter's accelerometer gain (k_p)
    bias_gain: float = 0.05  # 1/s², its gyro-bias integrator gain (k_i)
    speed_filter: float = 0.02  # s, time constant of the encoder speed filter
    pwm_bits: int = 8  # voltage commands: duty resolution (2^bits − 1 steps per direction)


@dataclass(frozen=True)
class SimSpec:
    """Everything one log is made from (see :func:`profile_a`, :func:`profile_b`)."""

    profile: str
    seed: int
    duration: float  # s of log
    plant: PlantParams  # the true plant
    nominal: PlantParams  # what the log's owner believes (log.toml's [robot]), and the controller's model
    imu: ImuModel
    controller: ControllerSpec
    initial: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # (θ, θ̇, ψ, ψ̇, α, α̇) at t = 0; at rest before if velocities are 0
    targets: tuple = ()  # Target, in time order
    pushes: tuple = ()  # Push
    motor: MotorParams | None = None  # None: ideal torque sources
    motor_nominal: MotorParams | None = None  # the motors as the owner believes them ([motor])
    encoder_counts: int = 1440  # per wheel revolution
    physics_rate: float = 1000.0  # Hz (RK4)
    log_periods_ms: tuple = ()  # () : a row at every control tick; (lo, hi): rows every lo..hi ms (uniform, jittered)
    log_rate: float | None = None  # Hz, log.toml's control_rate (None: the controller's rate)
    log_start: float = 0.0  # s: the first logged row (the encoders count from t = 0, power-up)
    variant: str = "default"


# ---- the generator's own estimator and controller -------------------------------------------------
class OnBoard:
    """The robot's firmware: a complementary filter for θ (gyro integrated, corrected towards the
    accelerometer's tilt, a PI on the gyro bias), encoder odometry for ψ and α, the LQR and the
    heading PD. Acts on readings only (never on the truth)."""

    def __init__(self, spec: SimSpec):
        c, nom = spec.controller, spec.nominal
        self.c, self.nom = c, nom
        A, B = linearise(nom)
        rN = nom.r
        Q = np.diag([1.0 / c.theta_max ** 2, 1.0 / c.theta_dot_max ** 2, (rN / c.position_max) ** 2,
                     (rN / c.speed_max) ** 2])
        Rm = np.array([[1.0 / c.torque_max ** 2]])
        P = solve_continuous_are(A, B, Q, Rm)
        self.K = (np.linalg.solve(Rm, B.T @ P)).ravel()  # u = −K x
        d = nom.derived()
        bor = nom.b / nom.r
        J, cy = d["m33"], 2.0 * bor * bor * (nom.d_b + nom.d_w)
        wn = c.heading_bandwidth
        # yaw: J α̈ = −c_y α̇ + (2b/r) u_α, u_α = k_p (α_d − α) + k_d (α̇_d − α̇): a double pole at −ω_n;
        # where the wheels' friction alone damps more than that (c_y > 2 ω_n J), no derivative gain
        # and the slow pole at −ω_n (the other one, faster, at −(c_y/J − ω_n))
        if cy < 2.0 * wn * J:
            self.kp, self.kd = J * wn * wn / (2.0 * bor), (2.0 * wn * J - cy) / (2.0 * bor)
        else:
            self.kp, self.kd = wn * (cy - wn * J) / (2.0 * bor), 0.0
        self.motor = spec.motor_nominal
        self.mount = spec.imu.mount_pitch  # the firmware knows its own IMU's mounting (it balances)
        self.theta = None
        self.bias = 0.0
        self.rate_y = 0.0
        self.theta0 = 0.0
        self.qbar = self.qdif = None
        self.qbar_dot = self.qdif_dot = 0.0
        self.alpha0 = spec.initial[4]
        self.A, self.B = A, B
        self.u_last = 0.0  # N·m, the last total torque commanded
        q = 2 ** (spec.imu.bits - 1)
        self.gyro_fs = spec.imu.gyro_range * (1.0 - 1.5 / q)  # a reading this large is taken as clipped
        self.accel_fs = spec.imu.accel_range * (1.0 - 1.5 / q)
        self.age = spec.imu.latency + (0.5 / spec.imu.rate if spec.imu.sampling == "mean" else 0.0)

    def imu(self, gyro, accel, dt: float) -> None:
        cb, sb = math.cos(self.mount), math.sin(self.mount)
        # IMU axes to body axes: v_body = R_y(β) v_imu (the pitch rate is on y either way)
        gy = gyro[1]
        ax, az = cb * accel[0] + sb * accel[2], -sb * accel[0] + cb * accel[2]
        tilt = math.atan2(-ax, az)
        accel_clipped = any(abs(v) >= self.accel_fs for v in accel)
        if self.theta is None:
            self.theta = self.theta0 = tilt
            self.rate_y = gy - self.bias
            return
        if abs(gy) >= self.gyro_fs:
            # a clipped gyro says "at least the full scale": the firmware propagates the rate with
            # its linear model's θ̈ instead (never below the full scale), a common saturation fallback
            th, thd, _, psd, _, _ = self.estimate()
            acc = self.A[1, 0] * th + self.A[1, 1] * thd + self.A[1, 3] * psd + self.B[1, 0] * self.u_last
            rate = self.rate_y + acc * dt
            gy = math.copysign(max(abs(rate), self.gyro_fs), gy) + self.bias
        e = 0.0 if accel_clipped else tilt - self.theta  # a clipped accelerometer is no tilt
        self.theta += (gy - self.bias + self.c.filter_gain * e) * dt
        self.bias -= self.c.bias_gain * e * dt
        self.rate_y = gy - self.bias

    def encoders(self, ql: float, qr: float, dt: float) -> None:
        qbar, qdif = 0.5 * (ql + qr), 0.5 * (qr - ql)
        if self.qbar is not None and dt > 0.0:
            a = dt / (self.c.speed_filter + dt)
            self.qbar_dot += a * ((qbar - self.qbar) / dt - self.qbar_dot)
            self.qdif_dot += a * ((qdif - self.qdif) / dt - self.qdif_dot)
        self.qbar, self.qdif = qbar, qdif

    def estimate(self) -> tuple:
        """(θ, θ̇, ψ, ψ̇, α, α̇) now: θ predicted over the IMU sample's age."""
        th = self.theta + self.rate_y * self.age
        bor = self.nom.b / self.nom.r
        return (th, self.rate_y, self.qbar + th - self.theta0, self.qbar_dot + self.rate_y,
                self.alpha0 + self.qdif / bor, self.qdif_dot / bor)

    def command(self, ref: tuple) -> tuple[float, float]:
        """(left, right): torques N·m (ideal sources) or voltages V (motors) for the reference
        (p_d m, v_d m/s, α_d rad, α̇_d rad/s)."""
        th, thd, ps, psd, al, ald = self.estimate()
        rN = self.nom.r
        # the position error clipped (as firmware does): a large one would otherwise lean the robot over
        e_max = self.c.position_error_limit / rN
        x = (th, thd, min(e_max, max(-e_max, ps - ref[0] / rN)), psd - ref[1] / rN)
        u = -sum(k * v for k, v in zip(self.K, x))
        ua = self.kp * (ref[2] - al) + self.kd * (ref[3] - ald)
        lim = self.c.torque_limit
        tl = min(lim, max(-lim, 0.5 * u - ua))
        tr = min(lim, max(-lim, 0.5 * u + ua))
        self.u_last = tl + tr
        if self.motor is None:
            return tl, tr
        m = self.motor
        wl = self.qbar_dot - self.qdif_dot  # each wheel's speed relative to the body, from the encoders
        wr = self.qbar_dot + self.qdif_dot
        steps = (1 << self.c.pwm_bits) - 1
        out = []
        for tau, w in ((tl, wl), (tr, wr)):
            v = tau * m.resistance / m.k + m.k * w  # the torque's current, plus back-EMF compensation
            duty = min(1.0, max(-1.0, v / m.supply))
            out.append(round(duty * steps) / steps * m.supply)
        return out[0], out[1]


class Ramp:
    """A reference that goes to its target with a speed and an acceleration limit (a trapezoid)."""

    def __init__(self, x0: float, vmax: float, amax: float):
        self.x, self.v, self.vmax, self.amax = float(x0), 0.0, vmax, amax

    def step(self, target: float, dt: float) -> tuple[float, float]:
        err = target - self.x
        goal = math.copysign(min(self.vmax, math.sqrt(2.0 * self.amax * abs(err))), err)
        dv = min(self.amax * dt, max(-self.amax * dt, goal - self.v))
        self.v += dv
        self.x += self.v * dt
        if abs(target - self.x) < 1e-9 or (target - self.x) * err < 0.0:  # arrived (or passed it): stop there
            if abs(self.v) <= self.amax * dt * 2.0:
                self.x, self.v = target, 0.0
        return self.x, self.v


# ---- the simulation --------------------------------------------------------------------------------
@dataclass
class SimResult:
    """What :func:`simulate` produced: the spec, the sensors' drawn constants, the log's rows and
    the truth at every physics step (``t`` (n,) s, ``states`` (n, 6)), the references at every
    control tick (``ref_t``, ``ref`` (m, 4): p_d m, v_d m/s, α_d rad, α̇_d rad/s) and counts of
    clipped samples."""

    spec: SimSpec
    constants: dict
    t: np.ndarray
    states: np.ndarray
    imu_rows: list  # (t, gyro (3,), accel (3,))
    encoder_rows: list  # (t, left, right) counts
    command_rows: list  # (t, left, right) as applied from t: N·m or V
    ref_t: np.ndarray
    ref: np.ndarray
    clipped: dict = field(default_factory=dict)
    log_t0: float = 0.0

    @property
    def dt(self) -> float:
        return 1.0 / self.spec.physics_rate


def _whole(x: float, what: str) -> int:
    k = round(x)
    if abs(x - k) > 1e-9 * max(1.0, abs(x)):
        raise ValueError(f"{what} must be a whole number, got {x!r}")
    return int(k)


def _imu_rotation(beta: float) -> np.ndarray:
    """R_y(β)ᵀ: a body-axes vector in the IMU's axes."""
    c, s = math.cos(beta), math.sin(beta)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def simulate(spec: SimSpec) -> SimResult:
    """Run ``spec``: the plant by RK4 at the physics rate, the firmware at its rate, the IMU and the
    encoders, the log's rows (see the module docstring)."""
    rng = np.random.default_rng(spec.seed)
    r_const, r_gyro, r_accel, r_vib, r_jitter = rng.spawn(5)
    h = 1.0 / spec.physics_rate
    imu = spec.imu
    ctrl_every = _whole(spec.physics_rate / spec.controller.rate, "physics rate / control rate")
    imu_every = _whole(spec.physics_rate / imu.rate, "physics rate / IMU rate")
    lat = _whole(imu.latency * spec.physics_rate, "IMU latency × physics rate")
    n_steps = _whole((spec.log_start + spec.duration) * spec.physics_rate, "(log start + duration) × physics rate")

    # the sensors' constants, drawn once (power-up)
    gyro_bias = r_const.normal(0.0, imu.gyro_bias_sigma, 3)
    accel_bias = r_const.normal(0.0, imu.accel_bias_sigma, 3)
    gyro_scale = r_const.normal(0.0, imu.scale_sigma, 3) if imu.scale_sigma > 0 else np.zeros(3)
    accel_scale = r_const.normal(0.0, imu.scale_sigma, 3) if imu.scale_sigma > 0 else np.zeros(3)
    phase = r_const.random(2)  # counts: where each encoder's first edge lies at power-up
    n_samples = n_steps // imu_every + 2
    sg, sa = imu.white_sigma()
    gyro_noise = r_gyro.normal(0.0, 1.0, (n_samples, 3)) * sg
    accel_noise = r_accel.normal(0.0, 1.0, (n_samples, 3)) * sa
    if imu.vibration_gyro > 0 or imu.vibration_accel > 0:
        gyro_noise += r_vib.normal(0.0, 1.0, (n_samples, 3)) * imu.vibration_gyro
        accel_noise += r_vib.normal(0.0, 1.0, (n_samples, 3)) * imu.vibration_accel
    rot = _imu_rotation(imu.mount_pitch)
    lsb_g = imu.gyro_range / 2 ** (imu.bits - 1)
    lsb_a = imu.accel_range / 2 ** (imu.bits - 1)
    code_lo, code_hi = -2 ** (imu.bits - 1), 2 ** (imu.bits - 1) - 1
    clipped = {"gyro": [0, 0, 0], "accel": [0, 0, 0]}

    def reading(true_f, true_w, j):
        """The IMU's sample j from the true (specific force, angular velocity) in body axes."""
        w = rot @ np.asarray(true_w)
        f = rot @ np.asarray(true_f)
        gy = (1.0 + gyro_scale) * w + gyro_bias + gyro_noise[j]
        ac = (1.0 + accel_scale) * f + accel_bias + accel_noise[j]
        out = []
        for y, lsb, name in ((gy, lsb_g, "gyro"), (ac, lsb_a, "accel")):
            codes = np.floor(y / lsb + 0.5)
            over = (codes < code_lo) | (codes > code_hi)
            for i in np.flatnonzero(over):
                clipped[name][i] += 1
            out.append(tuple(float(v) for v in np.clip(codes, code_lo, code_hi) * lsb))
        return out[0], out[1]

    dyn = Dynamics(spec.plant, spec.motor, imu.position)
    pushes = tuple(spec.pushes)
    push = (lambda t: sum(p.at(t) for p in pushes)) if pushes else None
    board = OnBoard(spec)
    c = spec.controller
    pos_ramp = Ramp(0.0, c.drive_speed, c.drive_accel)  # the firmware's position counts from power-up
    head_ramp = Ramp(spec.initial[4], c.turn_rate, c.turn_accel)
    targets = sorted(spec.targets, key=lambda g: g.time)
    p_target, a_target = 0.0, spec.initial[4]
    ti = 0

    s = tuple(float(v) for v in spec.initial)
    # before t = 0 the robot held this state (at rest, if its velocities are 0): the samples on
    # their way at t = 0 are of it
    rest_in = (0.0, 0.0)
    acc0 = dyn.accelerations(s, *rest_in) if any(s[i] for i in (1, 3, 5)) else (0.0, 0.0, 0.0)
    f0, w0 = dyn.imu_true(s, acc0)
    queue = []  # (arrival step, gyro, accel)
    j_sample = 0
    for k in range(-lat, 0):
        if k % imu_every == 0:
            queue.append((k + lat, *reading(f0, w0, j_sample)))
            j_sample += 1
    counts_per_rad = spec.encoder_counts / (2.0 * math.pi)
    bor = spec.plant.b / spec.plant.r
    q0 = (s[2] - s[0], s[2] - s[0])  # (q_l, q_r) at power-up: ψ_j = ψ ∓ (b/r)(α − α(0))

    def counts(state):
        ql = state[2] - bor * (state[4] - spec.initial[4]) - state[0]
        qr = state[2] + bor * (state[4] - spec.initial[4]) - state[0]
        return (math.floor((ql - q0[0]) * counts_per_rad + phase[0]),
                math.floor((qr - q0[1]) * counts_per_rad + phase[1]))

    # the log's rows: at every control tick, or at jittered ticks
    log_first = _whole(spec.log_start * spec.physics_rate, "log start × physics rate")
    if spec.log_periods_ms:
        lo, hi = spec.log_periods_ms
        per = []
        n = log_first
        while n <= n_steps:
            per.append(n)
            n += int(r_jitter.integers(lo, hi + 1)) * _whole(spec.physics_rate / 1000.0, "physics rate / 1 kHz")
        log_steps = set(per)
    else:
        log_steps = None

    states = np.empty((n_steps + 1, 6))
    imu_rows, enc_rows, cmd_rows, ref_rows, ref_t = [], [], [], [], []
    cmd = (0.0, 0.0)
    quad = [0.0] * 6  # the running integral of the true IMU outputs since the last sample
    last_point = (f0, w0)
    newest = None  # the newest IMU sample delivered since the last logged row
    last_ctrl_t = None
    last_imu_t = None
    for n in range(n_steps + 1):
        t = n * h
        states[n] = s
        # the IMU samples at its instants (the interval ending now)
        if n % imu_every == 0:
            if n == 0:
                tf, tw = f0, w0
            elif imu.sampling == "mean":
                T = imu_every * h
                tf, tw = tuple(v / T for v in quad[:3]), tuple(v / T for v in quad[3:])
            else:
                tf, tw = last_point
            queue.append((n + lat, *reading(tf, tw, j_sample)))
            j_sample += 1
            quad = [0.0] * 6
        if n % ctrl_every == 0:
            # what arrived by now goes to the firmware, in order
            arrived = [q for q in queue if q[0] <= n]
            queue = [q for q in queue if q[0] > n]
            for _, gy, ac in arrived:
                board.imu(gy, ac, 1.0 / imu.rate if last_imu_t is not None else 0.0)
                last_imu_t = t
                newest = (gy, ac)
            cl, cr = counts(s)
            res = 1.0 / counts_per_rad
            board.encoders(cl * res, cr * res, t - last_ctrl_t if last_ctrl_t is not None else 0.0)
            last_ctrl_t = t
            while ti < len(targets) and targets[ti].time <= t + 1e-12:
                if targets[ti].position is not None:
                    p_target = targets[ti].position
                if targets[ti].heading is not None:
                    a_target = targets[ti].heading
                ti += 1
            dt_c = 1.0 / c.rate
            pd, vd = pos_ramp.step(p_target, dt_c) if n > 0 else (pos_ramp.x, 0.0)
            ad, avd = head_ramp.step(a_target, dt_c) if n > 0 else (head_ramp.x, 0.0)
            ref = (pd, vd, ad, avd)
            cmd = board.command(ref)
            ref_rows.append(ref)
            ref_t.append(t)
            logged = n >= log_first and (log_steps is None or n in log_steps)
            if logged:
                if newest is not None:
                    imu_rows.append((t, newest[0], newest[1]))
                    newest = None
                enc_rows.append((t, cl, cr))
                cmd_rows.append((t, float(cmd[0]), float(cmd[1])))
        if n == n_steps:
            break
        s, qd = dyn.step(s, h, cmd[0], cmd[1], push, t)
        quad = [a + b for a, b in zip(quad, qd)]
        if imu.sampling == "point" and (n + 1) % imu_every == 0:
            acc = dyn.accelerations(s, cmd[0], cmd[1], push(t + h) if push else 0.0)
            last_point = dyn.imu_true(s, acc)  # the instant's value with the input that acted up to it
        if not all(math.isfinite(v) for v in s):
            raise FloatingPointError(f"the simulation diverged at t = {t:.3f} s")

    constants = {"gyro_bias": gyro_bias.tolist(), "accel_bias": accel_bias.tolist(),
                 "gyro_scale": gyro_scale.tolist(), "accel_scale": accel_scale.tolist(),
                 "encoder_phase_at_power_up": phase.tolist()}
    return SimResult(spec, constants, np.arange(n_steps + 1) * h, states, imu_rows, enc_rows, cmd_rows,
                     np.array(ref_t), np.array(ref_rows), clipped, log_first * h)


# ---- the log writer ------------------------------------------------------------------------------
def _num(v: float) -> str:
    """A float as its shortest round-trip repr (a whole float keeps its '.0')."""
    return repr(float(v))


def _csv(path: Path, header: tuple, rows) -> None:
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(header) + "\n")
        for row in rows:
            fh.write(",".join(v if isinstance(v, str) else (str(v) if isinstance(v, int) else _num(v)) for v in row)
                     + "\n")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return _num(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(e) for e in v) + "]"
    raise TypeError(f"no TOML for {v!r}")


def truth_instants(result: SimResult) -> np.ndarray:
    """The physics steps (indices) of the replay's control instants (where the twin's replay
    compares the truth): t_0 + k / log rate from the first logged command, or, where the rows
    come at irregular periods (``log_periods_ms``), the command rows' own instants (the replay's
    instants are then its rows)."""
    spec = result.spec
    if spec.log_periods_ms and min(spec.log_periods_ms) != max(spec.log_periods_ms):
        return np.array([_whole(t * spec.physics_rate, "command × physics rate") for t, _, _ in result.command_rows])
    rate = spec.log_rate or spec.controller.rate
    every = _whole(spec.physics_rate / rate, "physics rate / log rate")
    first = _whole(result.command_rows[0][0] * spec.physics_rate, "first command × physics rate")
    last = _whole(result.command_rows[-1][0] * spec.physics_rate, "last command × physics rate")
    return np.arange(first, last + 1, every)


def write_log(result: SimResult, out, version: int = FORMAT_VERSION, noise_figures: bool = True) -> Path:
    """Write ``result`` as a sensor log in directory ``out``: log.toml, imu.csv, encoders.csv,
    commands.csv, truth.csv (with the state-truth columns) and the sidecar robot_sim.json.
    ``version`` 1 (what version 1 cannot say goes into the sidecar only) or 2 (the IMU's sampling,
    rate, latency, mounting orientation, ranges and constants' figures, the encoders, the commands'
    unit and semantics, the motors, all in log.toml: a profile-B log is then written as it is, volts
    sampled at each row, an IMU pitched by its mounting angle). ``noise_figures`` (version 2): write
    the true white noise of one row (``[imu.gyro]``/``[imu.accel]`` ``noise_density``, or ``sigma``
    where vibration adds to it); False leaves them out, as a log whose owner does not know them
    (a reader then takes a preset's datasheet figures). Returns the directory."""
    if version not in (1, 2):
        raise ValueError(f"version must be 1 or 2, got {version!r}")
    if version == 2:
        return _write_log_v2(result, Path(out), noise_figures)
    spec = result.spec
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    imu = spec.imu
    nom = spec.nominal
    rate = spec.log_rate or spec.controller.rate
    _csv(out / "imu.csv", ("t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"),
         ((t, *g, *a) for t, g, a in result.imu_rows))
    _csv(out / "encoders.csv", ("t", "left", "right"), result.encoder_rows)
    voltage = spec.motor is not None
    supply = spec.motor.supply if voltage else 1.0
    # voltages as a PWM duty (V / supply): version 1 can say duty, not volts, nor that they were sampled
    _csv(out / "commands.csv", ("t", "ul", "ur"),
         ((t, a / supply, b / supply) if voltage else (t, a, b) for t, a, b in result.command_rows))
    # the truth at the replay's control instants, with the EKF's state truth
    idx = truth_instants(result)
    st = result.states
    bor = spec.plant.b / spec.plant.r
    a0 = spec.initial[4]
    n0 = idx[0]
    rows = []
    for n in idx:
        th, thd, ps, psd, al, ald = st[n]
        rows.append((float(n) / spec.physics_rate, th, thd, ps, psd, al, ald, ps - bor * (al - a0),
                     ps + bor * (al - a0), *result.constants["gyro_bias"]))
    _csv(out / "truth.csv", ("t", "theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot", "psi_l", "psi_r",
                             "gyro_bias_x", "gyro_bias_y", "gyro_bias_z"), rows)
    # the encoders' phase as the twin's truth defines it: counts = floor((q − q(t_0)) c + φ), t_0 the
    # replay's first instant (here q(t_0) may differ from the power-up angle when the log starts late)
    c = spec.encoder_counts / (2.0 * math.pi)
    x0 = st[0]
    q_pu = (x0[2] - x0[0], x0[2] - x0[0])
    s0 = st[n0]
    q_t0 = (s0[2] - bor * (s0[4] - a0) - s0[0], s0[2] + bor * (s0[4] - a0) - s0[0])
    ph = result.constants["encoder_phase_at_power_up"]
    phase = [ph[j] + (q_t0[j] - q_pu[j]) * c for j in range(2)]
    robot = {k: float(getattr(nom, k)) for k in ("m_w", "m_b", "n_wa", "n_wd", "n_yb", "n_zb", "l", "d_b", "d_w",
                                                   "g")}
    robot["n_xb"] = float(nom.roll_inertia)
    sets = [f"sensors.imu_rate={_num(rate if voltage else imu.rate)}",
            f"sensors.imu_latency={_num(0.0 if voltage else imu.latency)}",
            f"sensors.gyro.full_scale={_num(imu.gyro_range)}", f"sensors.accel.full_scale={_num(imu.accel_range)}",
            'plant.motor="dc"' if voltage else 'plant.motor="ideal"']
    lines = [f'format = "mtwip-sensor-log"', f"version = {FORMAT_VERSION}", f"control_rate = {_num(rate)}",
             f"wheel_radius = {_num(nom.r)}", f"track = {_num(2.0 * nom.b)}",
             f"encoder_counts = {int(spec.encoder_counts)}", f"imu_position = {_toml_value(list(imu.position))}",
             f"initial_heading = {_num(spec.initial[4])}", 'scenario = "paper-exp1"', f"set = {_toml_value(sets)}",
             f'source = "{GENERATOR}: profile {spec.profile} ({spec.variant}), seed {spec.seed}; see robot_sim.json"',
             "", "[robot]", *(f"{k} = {_num(v)}" for k, v in robot.items()), ""]
    if voltage:
        m = spec.motor_nominal or spec.motor
        lines += ["[motor]", f"supply_voltage = {_num(m.supply)}", f"stall_torque = {_num(m.stall_torque)}",
                  f"no_load_speed = {_num(m.no_load_speed)}", f"pwm_bits = {int(spec.controller.pwm_bits)}",
                  "back_emf_compensation = false", "", "[commands]", 'unit = "duty"', ""]
    else:
        lines += ["[commands]", 'unit = "N·m"', ""]
    lines += ["[truth]", f"gyro_scale = {_toml_value(result.constants['gyro_scale'])}",
              f"accel_scale = {_toml_value(result.constants['accel_scale'])}",
              f"encoder_phase = {_toml_value(phase)}", f"wheel_radius = {_num(spec.plant.r)}", ""]
    (out / "log.toml").write_text("\n".join(lines), encoding="utf-8")
    (out / "robot_sim.json").write_text(json.dumps(sidecar(result), indent=1, sort_keys=True) + "\n",
                                        encoding="utf-8")
    return out


def _truth_rows(result: SimResult, bias: list) -> list:
    """truth.csv's rows at the replay's control instants: the exact states, the wheels' absolute
    angles and the gyro's (constant) bias ``bias`` rad/s."""
    spec = result.spec
    st = result.states
    bor = spec.plant.b / spec.plant.r
    a0 = spec.initial[4]
    rows = []
    for n in truth_instants(result):
        th, thd, ps, psd, al, ald = st[n]
        rows.append((float(n) / spec.physics_rate, th, thd, ps, psd, al, ald, ps - bor * (al - a0),
                     ps + bor * (al - a0), *bias))
    return rows


def _encoder_phase(result: SimResult) -> list:
    """φ_j in counts = floor((q_j − q_j(t_0)) counts/rad + φ_j), t_0 the replay's first control
    instant (the log format's definition; the encoders count from power-up, which may be earlier)."""
    spec = result.spec
    st = result.states
    bor = spec.plant.b / spec.plant.r
    a0 = spec.initial[4]
    c = spec.encoder_counts / (2.0 * math.pi)
    x0, s0 = st[0], st[truth_instants(result)[0]]
    q_pu = (x0[2] - x0[0], x0[2] - x0[0])
    q_t0 = (s0[2] - bor * (s0[4] - a0) - s0[0], s0[2] + bor * (s0[4] - a0) - s0[0])
    ph = result.constants["encoder_phase_at_power_up"]
    return [ph[j] + (q_t0[j] - q_pu[j]) * c for j in range(2)]


def _row_sigma(imu: ImuModel, row_rate: float) -> tuple[float, float]:
    """One row's white-noise σ (gyro rad/s, accel m/s²). A mean sample at the IMU's rate has
    density × √rate; a point sample decimated to fewer rows is still one sample of the IMU's
    rate (its noise is not averaged down by the decimation), plus the vibration."""
    sg, sa = imu.white_sigma()
    if imu.sampling == "mean" and abs(row_rate - imu.rate) > 1e-9 * imu.rate:
        raise ValueError("mean samples are logged at the IMU's own rate only")
    return math.hypot(sg, imu.vibration_gyro), math.hypot(sa, imu.vibration_accel)


def _write_log_v2(result: SimResult, out: Path, noise_figures: bool) -> Path:
    """:func:`write_log`'s version 2 (docs/reference/sensor-log.md)."""
    spec = result.spec
    out.mkdir(parents=True, exist_ok=True)
    imu = spec.imu
    nom = spec.nominal
    rate = spec.log_rate or spec.controller.rate
    voltage = spec.motor is not None
    # rows decimated from a faster loop (profile B): one IMU row per logged row, the IMU's "rate" is the rows'
    imu_rate = rate if spec.log_periods_ms else imu.rate
    _csv(out / "imu.csv", ("t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"),
         ((t, *g, *a) for t, g, a in result.imu_rows))
    _csv(out / "encoders.csv", ("t", "left", "right"), result.encoder_rows)
    _csv(out / "commands.csv", ("t", "ul", "ur"), result.command_rows)  # N·m (ideal) or V (sampled), as applied
    # the state truth in the body's axes, as the replay's estimators see the readings (v_body = R_y(β) v_imu);
    # the scale factors are per IMU axis (exact for y, the pitch axis; x and z are 0.07 rad from the body's)
    rot = _imu_rotation(imu.mount_pitch).T
    bias_body = (rot @ np.asarray(result.constants["gyro_bias"])).tolist()
    _csv(out / "truth.csv", ("t", "theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot", "psi_l", "psi_r",
                             "gyro_bias_x", "gyro_bias_y", "gyro_bias_z"), _truth_rows(result, bias_body))
    sg, sa = _row_sigma(imu, imu_rate)
    robot = {k: float(getattr(nom, k)) for k in ("m_w", "m_b", "n_wa", "n_wd", "n_yb", "n_zb", "l", "d_b", "d_w",
                                                   "g")}
    robot["n_xb"] = float(nom.roll_inertia)
    lines = ['format = "mtwip-sensor-log"', "version = 2", f"control_rate = {_num(rate)}",
             f"wheel_radius = {_num(nom.r)}", f"track = {_num(2.0 * nom.b)}",
             f"initial_heading = {_num(spec.initial[4])}",
             f'source = "{GENERATOR}: profile {spec.profile} ({spec.variant}), seed {spec.seed}; see robot_sim.json"',
             "", "[imu]", f'sampling = "{imu.sampling}"', f"rate = {_num(imu_rate)}",
             f"latency = {_num(imu.latency)}", f"position = {_toml_value(list(imu.position))}",
             f"orientation = {_toml_value([0.0, float(imu.mount_pitch), 0.0])}", 'preset = "mpu6050"', ""]
    vib = imu.vibration_gyro > 0 or imu.vibration_accel > 0
    for name, density, sigma, bias, full in (("gyro", imu.gyro_density, sg, imu.gyro_bias_sigma, imu.gyro_range),
                                             ("accel", imu.accel_density, sa, imu.accel_bias_sigma, imu.accel_range)):
        lines.append(f"[imu.{name}]")
        if noise_figures:
            # with vibration (or decimated point samples) a density does not describe a row: its σ does
            lines.append(f"sigma = {_num(sigma)}" if vib or imu_rate != imu.rate else
                         f"noise_density = {_num(density)}")
        lines += ["bias_random_walk = 0.0", f"turn_on_bias = {_num(bias)}",  # constant biases, drawn once
                  f"scale_factor_error = {_num(imu.scale_sigma)}", f"full_scale = {_num(full)}",
                  f"bits = {int(imu.bits)}", ""]
    lines += ["[encoders]", f"counts_per_rev = {int(spec.encoder_counts)}", 'on = "wheel"', "latency = 0.0", ""]
    if voltage:
        m = spec.motor_nominal or spec.motor
        lines += ["[commands]", 'unit = "V"', 'semantics = "sampled"', "", "[motor]", 'kind = "dc"',
                  f"supply_voltage = {_num(m.supply)}", f"stall_torque = {_num(m.stall_torque)}",
                  f"no_load_speed = {_num(m.no_load_speed)}", f"pwm_bits = {int(spec.controller.pwm_bits)}",
                  "dead_band = 0.0", "inductance = 0.0", "back_emf_compensation = false", ""]
    else:
        lines += ["[commands]", 'unit = "N·m"', 'semantics = "held"', "", "[motor]", 'kind = "ideal"', ""]
    lines += ["[robot]", *(f"{k} = {_num(v)}" for k, v in robot.items()), ""]
    lines += ["[truth]", f"gyro_scale = {_toml_value(result.constants['gyro_scale'])}",
              f"accel_scale = {_toml_value(result.constants['accel_scale'])}",
              f"encoder_phase = {_toml_value(_encoder_phase(result))}", f"wheel_radius = {_num(spec.plant.r)}", ""]
    (out / "log.toml").write_text("\n".join(lines), encoding="utf-8")
    side = sidecar(result)
    side["format_version_written"] = 2
    side["noise_figures_written"] = bool(noise_figures)
    side["row_white_sigma"] = {"gyro_rad_s": sg, "accel_m_s2": sa}
    side["commands"]["note"] = ("commands.csv holds the motor voltage (V) sampled at the row's instant "
                                "(log.toml: unit = \"V\", semantics = \"sampled\")" if voltage else
                                side["commands"]["note"])
    side["log"]["truth"] += "; version 2: gyro_bias_* in the body's axes (R_y(mount_pitch) applied)"
    (out / "robot_sim.json").write_text(json.dumps(side, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return out


def sidecar(result: SimResult) -> dict:
    """The generator's own record of the truth and the settings (``robot_sim.json``), including what
    version 1 of the log format cannot say."""
    spec = result.spec
    imu = spec.imu
    d = {
        "generator": GENERATOR, "format_version_written": FORMAT_VERSION,
        "profile": spec.profile, "variant": spec.variant, "seed": spec.seed, "duration_s": spec.duration,
        "physics": {"integrator": "classical RK4", "rate_hz": spec.physics_rate,
                    "equations": "paper-notes equation (1), all three, n_xb = n_yb"},
        "plant_true": asdict(spec.plant) | {"n_xb": spec.plant.roll_inertia},
        "plant_nominal": asdict(spec.nominal) | {"n_xb": spec.nominal.roll_inertia},
        "plant_scale": {k: getattr(spec.plant, k) / getattr(spec.nominal, k)
                        for k in ("m_w", "m_b", "n_wa", "n_wd", "n_yb", "n_zb", "r", "b", "l", "d_b", "d_w")},
        "motors": None if spec.motor is None else {
            "true": asdict(spec.motor) | {"k_wheel_Nm_per_A": spec.motor.k, "stall_torque_Nm": spec.motor.stall_torque,
                                          "no_load_speed_rad_s": spec.motor.no_load_speed},
            "nominal": None if spec.motor_nominal is None else asdict(spec.motor_nominal),
            "model": "τ = k (V − k ω)/R per wheel, ω = ψ̇_j − θ̇, V clipped to ±supply, inductance neglected"},
        "commands": ({"quantity": "voltage", "unit": "V", "semantics": "sampled",
                      "note": "commands.csv holds V / supply_voltage (a duty, what version 1 can say) sampled at "
                              "the row's instant; the inner loop changes the voltage every "
                              f"{1000.0 / spec.controller.rate:g} ms, it is not held between rows",
                      "supply_voltage_V": spec.motor.supply, "pwm_bits": spec.controller.pwm_bits}
                     if spec.motor is not None else
                     {"quantity": "torque", "unit": "N·m", "semantics": "held",
                      "note": "ideal torque sources: the command acts unchanged until the next control instant"}),
        "imu": asdict(imu) | {"white_sigma_per_sample": list(imu.white_sigma()),
                              "axes": "the body's rotated by mount_pitch about y: v_imu = R_y(mount_pitch)^T v_body",
                              "sampling_note": ("mean over the sample interval" if imu.sampling == "mean" else
                                                "point sample at the instant (the inner loop's latest)")},
        "imu_constants": result.constants,
        "clipped_samples": result.clipped,
        "encoders": {"counts_per_rev": spec.encoder_counts, "latency_s": 0.0,
                     "model": "floor((q − q_power_up) counts/rad + phase), q = ψ_j − θ"},
        "controller": asdict(spec.controller) | {"lqr_gain": None},
        "initial_state": dict(zip(("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot"), spec.initial)),
        "targets": [asdict(g) for g in spec.targets],
        "pushes": [asdict(p) for p in spec.pushes],
        "log": {"control_rate_hz": spec.log_rate or spec.controller.rate,
                "row_periods_ms": list(spec.log_periods_ms) or None, "log_start_s": spec.log_start,
                "rows": {"imu": len(result.imu_rows), "encoders": len(result.encoder_rows),
                         "commands": len(result.command_rows)},
                "truth": "truth.csv at the replay's control instants (first command + k / control_rate), exact "
                         "states of the RK4 integration; gyro_bias_* and the [truth] scale factors are in the IMU's "
                         "axes (the body's unless mount_pitch is not 0); encoder_phase is φ in counts = "
                         "floor((q − q(t_0)) counts/rad + φ), t_0 the replay's first instant"},
    }
    d["controller"]["lqr_gain"] = OnBoard(spec).K.tolist()
    return d


# ---- the profiles ---------------------------------------------------------------------------------
def _schedule(rng: np.random.Generator, duration: float, start: float, pos_range: float, head_range: float,
              push_force: tuple, push_every: float, legs=(2.5, 3.5)) -> tuple[tuple, tuple]:
    """Targets and pushes: after ``start`` s standing still, legs of 2.5–3.5 s each, one of drive,
    turn, drive while turning, stand; a push about every ``push_every`` s in a standing leg."""
    targets, pushes = [], []
    t, p, a = start, 0.0, 0.0
    kinds = ("drive", "turn", "drive_turn", "drive", "turn", "stand")
    i = 0
    next_push = start + push_every * 0.8
    while t < duration - 1.5:
        kind = kinds[i % len(kinds)] if i < len(kinds) else str(rng.choice(kinds))
        i += 1
        leg = float(rng.uniform(*legs))
        if kind in ("drive", "drive_turn"):
            step = float(rng.uniform(0.25, 0.6)) * (1.0 if rng.random() < 0.5 else -1.0)
            if abs(p + step) > pos_range:
                step = -step
            p += step
        if kind in ("turn", "drive_turn"):
            a_new = float(rng.uniform(-head_range, head_range))
            if abs(a_new - a) < 0.6:
                a_new = a + math.copysign(0.8, a_new - a if a_new != a else 1.0)
                a_new = max(-head_range, min(head_range, a_new))
            a = a_new
        if kind == "stand" or (push_force and t >= next_push):
            f = float(rng.uniform(*push_force)) * (1.0 if rng.random() < 0.5 else -1.0) if push_force else 0.0
            if push_force:
                pushes.append(Push(round(t + 0.5, 3), round(float(rng.uniform(0.1, 0.2)), 3), f))
                next_push = t + push_every
                targets.append(Target(round(t + 1.5, 3), p if kind != "stand" else None,
                                      a if kind in ("turn", "drive_turn") else None))
                t += max(leg, 3.0)
                continue
        targets.append(Target(round(t, 3), p if kind in ("drive", "drive_turn") else None,
                              a if kind in ("turn", "drive_turn") else None))
        t += leg
    return tuple(targets), tuple(pushes)


A_SCALE = {"m_b": 1.15, "l": 0.9, "d_b": 1.5, "d_w": 1.5}  # profile A's true plant against Table III


def profile_a(seed: int = 0, duration: float = 20.0, variant: str = "default", scale_sigma: float = 0.01,
              plant_scale: dict | None = None, theta0: float | None = None, log_start: float = 0.0,
              **imu_overrides) -> SimSpec:
    """Issue 40's "independent simulator" (see the module docstring). ``variant``: "default",
    "clip" (a sharper catch from 0.35–0.45 rad: stiffer gains, clipping gyro and accelerometer) or
    "push" (pushes of 10–12 N); ``scale_sigma`` the scale factors' σ (0: every true scale factor
    zero); ``plant_scale`` the true plant's factors of Table III (default m_b × 1.15, l × 0.9,
    d_b and d_w × 1.5); ``theta0`` rad the tilt it is released from at rest at t = 0 (default
    drawn: within ±0.05 rad, or ±(0.35–0.45) rad for "clip"); ``log_start`` s when the logging
    starts (later than 0: a log that begins mid-motion, e.g. in the catch); ``imu_overrides``
    any :class:`ImuModel` field."""
    if variant not in ("default", "clip", "push"):
        raise ValueError(f"variant must be default, clip or push, got {variant!r}")
    rng = np.random.default_rng([seed, 40])  # the scenario's draws (the simulation's own streams use the seed)
    ctrl = ControllerSpec()
    if variant == "clip":
        drawn = float(rng.uniform(0.35, 0.45)) * (1.0 if rng.random() < 0.5 else -1.0)
        ctrl = replace(ctrl, theta_max=0.03, torque_max=0.1)  # stiffer: about 10 clipped gyro samples in the catch
    else:
        drawn = float(rng.uniform(-0.05, 0.05))
    theta0 = drawn if theta0 is None else float(theta0)  # (drawn either way: the schedule's draws stay the same)
    push_force = (10.0, 12.0) if variant == "push" else (3.0, 6.0)
    targets, pushes = _schedule(rng, duration, 2.0, 0.8, 1.5, push_force, 6.0)
    imu = replace(ImuModel(), scale_sigma=scale_sigma, **imu_overrides)
    plant = TABLE_III.scaled(**(A_SCALE if plant_scale is None else plant_scale))
    return SimSpec("A", seed, duration, plant, TABLE_III, imu, ctrl, (theta0, 0.0, 0.0, 0.0, 0.0, 0.0), targets,
                   pushes, variant=variant, log_start=float(log_start))


B_PLANT = PlantParams(m_w=0.045, m_b=0.71, n_wa=2.2e-5, n_wd=1.3e-5, n_yb=1.9e-3, n_zb=1.3e-3, r=0.030, b=0.08,
                      l=0.048, d_b=0.002, d_w=0.005)
B_NOMINAL = PlantParams(m_w=0.05, m_b=0.68, n_wa=2.5e-5, n_wd=1.5e-5, n_yb=1.5e-3, n_zb=1.2e-3, r=0.030, b=0.08,
                        l=0.055, d_b=0.001, d_w=0.003)
B_MOTOR = MotorParams(resistance=7.5, k_t=0.343 / 30.0, gear=30.0, supply=12.0)
B_MOTOR_NOMINAL = MotorParams(resistance=7.0, k_t=0.35 / 30.0, gear=30.0, supply=12.0)


def profile_b(seed: int = 0, duration: float | None = None, theta0: float | None = None, log_start: float = 0.0,
              **imu_overrides) -> SimSpec:
    """A real-robot-shaped log (see the module docstring): ``duration`` s (default drawn in
    12–20 s), ``theta0`` rad the lying tilt it starts from at rest (default drawn in
    0.45–0.55 rad), ``log_start`` s when the logging starts (later: a log that begins in
    motion); ``imu_overrides`` any :class:`ImuModel` field."""
    rng = np.random.default_rng([seed, 41])
    if duration is None:
        duration = round(float(rng.uniform(12.0, 20.0)), 3)
    if theta0 is None:
        theta0 = float(rng.uniform(0.45, 0.55))
    imu = replace(ImuModel(rate=1000.0, latency=0.0, sampling="point", position=(0.0, 0.0, 0.06),
                           mount_pitch=0.07, gyro_range=500.0 * DEG, accel_range=2.0 * G0,
                           accel_bias_sigma=0.02, vibration_gyro=0.05, vibration_accel=0.6), **imu_overrides)
    ctrl = ControllerSpec(rate=1000.0, theta_max=0.05, theta_dot_max=5.0, position_max=0.1, speed_max=0.5,
                          torque_max=0.1, torque_limit=0.6, drive_speed=0.25, drive_accel=0.5, turn_rate=1.5,
                          speed_filter=0.03, filter_gain=2.0, bias_gain=0.1)
    targets, pushes = _schedule(rng, duration + log_start, 3.0 + log_start, 0.5, 1.2, (), 1e9)
    return SimSpec("B", seed, duration, B_PLANT, B_NOMINAL, imu, ctrl, (theta0, 0.0, 0.0, 0.0, 0.0, 0.0), targets,
                   pushes, motor=B_MOTOR, motor_nominal=B_MOTOR_NOMINAL, log_periods_ms=(30, 33),
                   log_rate=1000.0 / 30.0, log_start=log_start)


def generate(out, profile: str = "A", seed: int = 0, **options) -> SimResult:
    """Simulate a profile (``"A"`` or ``"B"``, with :func:`profile_a` / :func:`profile_b`'s
    ``options``) and write its log into directory ``out``; returns the :class:`SimResult`. Two
    options are :func:`write_log`'s: ``version`` (1, the default, or 2) and ``noise_figures``."""
    version = options.pop("version", FORMAT_VERSION)
    noise_figures = options.pop("noise_figures", True)
    spec = {"A": profile_a, "B": profile_b}[profile.upper()](seed=seed, **options)
    result = simulate(spec)
    write_log(result, out, version=version, noise_figures=noise_figures)
    return result


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description="Write a sensor log from the independent simulator.")
    ap.add_argument("out")
    ap.add_argument("--profile", default="A", choices=("A", "B"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float)
    ap.add_argument("--variant", default="default", choices=("default", "clip", "push"))
    ap.add_argument("--scale-sigma", type=float, default=0.01)
    ap.add_argument("--format-version", type=int, default=FORMAT_VERSION, choices=(1, 2))
    ap.add_argument("--no-noise-figures", action="store_true", help="version 2: leave the white noise out")
    args = ap.parse_args(argv)
    opts = {} if args.duration is None else {"duration": args.duration}
    opts |= {"version": args.format_version, "noise_figures": not args.no_noise_figures}
    if args.profile == "A":
        opts |= {"variant": args.variant, "scale_sigma": args.scale_sigma}
    generate(args.out, args.profile, args.seed, **opts)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
