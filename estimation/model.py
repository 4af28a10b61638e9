"""What the estimator knows about the robot: equation (1) with the motors' driver.

The strapdown filter of :mod:`estimation.ekf` needs no dynamics model to fuse the IMU
and the encoders. Equation (1) with the commanded torques serves where there is no
(trustworthy) IMU sample: to coast through IMU dropouts, to test whether an IMU sample is
an outlier, and to predict across the sensors' latency.

State here: s = [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s), the controllers' state.

Actuators. The driver of :mod:`twin.actuators.dc_motor` sets its PWM duty from the
command plus back-EMF compensation at the shaft speed ω_k at the update, so over the
period the motor delivers τ_0 − c_e ω(t) with τ_0 = clip(τ*, current limit) + c_e ω_k
clipped to the stall torque: the back-EMF slope c_e acts exactly like extra body–wheel
damping, so the model is equation (1) with d_b + c_e and input τ_0.

Model uncertainty, per wheel (used for synthetic IMU samples only): the PWM step
(uniform, LSB/√12) and a torque-constant tolerance (σ = :data:`TORQUE_TOLERANCE` of the
torque; motor datasheets give ±10 %). The robot's own parameters are uncertain too
(Table III's figures "cannot be 100 % accurate"): :data:`MODEL_UNCERTAINTY` is the box
the estimator assumes them in, and :meth:`EstimatorModel.sensitivity` how a synthetic
sample moves with each; the filter carries the parameters' errors as random constants
while the model stands in for a sensor (:class:`estimation.ekf_filter.Coasting`).
"""
from __future__ import annotations

import math

import numpy as np

from twin.actuators.dc_motor import DCMotorParams
from twin.params import NOMINAL, RobotParams
from twin.plant.analytic import NO_TAU, rhs
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, EncoderSpec, ImuSpec

TORQUE_TOLERANCE = 0.05  # 1σ of the delivered torque relative to the command (±10 % at 2σ)
# Relative half-ranges (1) of the box the estimator assumes the robot's parameters in, each
# uniform inside it (σ = half-range / √3): the mass and the centre-of-mass height as the
# default robust balance design's box (twin.controllers.lmi.DEFAULT_UNCERTAIN), the pitch
# inertia as uncertain as the mass, and the viscous frictions known to a factor of two at
# best (the range calibration draws them from)
MODEL_UNCERTAINTY = {"m_b": 0.3, "l": 0.15, "n_yb": 0.3, "d_b": 1.0, "d_w": 1.0}
# RK4 steps of the model at most this many of the fastest damped mode's time constants
# (EstimatorModel.substeps): RK4 is stable up to h λ ≈ 2.8, and at h λ = 1 that mode is off by
# about (h λ)⁵/120 < 1 % a step (the twin's robots at 200 Hz: h λ ≤ 0.51, one step)
STIFF_STEP = 1.0
SENSITIVITY_STEP = 1e-4  # relative step of the central differences in sensitivity()
TH, THD, PS, PSD, AL, ALD = range(6)


class EstimatorModel:
    """Equation (1) with the motors' back-EMF, and the sensors' measurement models.

    Parameters
    ----------
    params : RobotParams
        The model the estimator assumes (the controllers' nominal one by default).
    motor : DCMotorParams or None
        The motors' driver specification (None: ideal torque sources).
    imu : ImuSpec
    encoders : EncoderSpec
    control_rate : float
        Hz; commands are held for 1 / control_rate s.
    """

    def __init__(self, params: RobotParams = NOMINAL, motor: DCMotorParams | None = None,
                 imu: ImuSpec = DEFAULT_IMU, encoders: EncoderSpec = DEFAULT_ENCODERS, control_rate: float = 200.0):
        p = params
        self.params, self.motor, self.imu, self.encoders = p, motor, imu, encoders
        self.dt = 1.0 / float(control_rate)
        self.c_e = 0.0 if motor is None else motor.electrical_damping
        self.m11, self.m12, self.m22 = p.m11, p.m12, p.m22
        # equation (1) with the back-EMF slope added to the body–wheel damping
        self.plant = p.replace(d_b=p.d_b + self.c_e)
        self.b_r = p.b / p.r
        self.r, self.g = p.r, p.g
        self.xi, self.zi = imu.position[0], imu.position[2]
        self.substeps = self._substeps()
        if motor is None:
            self.tau_max = self.i_tau = math.inf
            self.sigma_tau = 0.0
            self.compensates = False
        else:
            self.tau_max = motor.stall_torque
            self.i_tau = motor.k_t * motor.max_current
            self.sigma_tau = motor.stall_torque / motor.pwm_steps / math.sqrt(12.0)
            self.compensates = motor.back_emf_compensation

    def _substeps(self) -> int:
        """RK4 steps per control period: enough that each is at most :data:`STIFF_STEP` of the
        fastest damped mode's time constant 1/λ, λ the largest eigenvalue of M⁻¹D upright (the
        body–wheel and wheel–ground damping, the motors' back-EMF included, on (ψ̇, θ̇)) or the
        yaw's damping over its inertia.

        One step per period suffices for the twin's robots at 200 Hz (h λ ≤ 0.51, the yaw's). A
        hobby robot's log at 33 Hz with 12 V gear motors has h λ ≈ 5.6, past RK4's stability
        limit: one step per period predicted the body's mean rate over a period 4–17 rad/s off
        (from the true state), six steps within 0.1–0.3 rad/s of the truth."""
        p = self.plant
        m11, m12, m22 = self.m11, self.m12, self.m22
        det = m11 * m22 - m12 * m12
        db, dw = p.d_b, p.d_w
        a = 2.0 * (m22 * (dw + db) + m12 * db) / det
        b = -2.0 * (m22 * db + m12 * db) / det
        c = -2.0 * (m12 * (dw + db) + m11 * db) / det
        d = 2.0 * (m12 * db + m11 * db) / det
        tr, dt_ = a + d, a * d - b * c
        lam = 0.5 * tr + math.sqrt(max(0.25 * tr * tr - dt_, 0.0))
        lam = max(lam, p.yaw_damping / p.m33)
        if not math.isfinite(lam) or lam <= 0.0:
            return 1
        return max(1, math.ceil(self.dt * lam / STIFF_STEP))

    # ---- actuators ---------------------------------------------------------------------
    def delivered(self, x, ul: float, ur: float) -> tuple[float, float]:
        """τ_0 per wheel (N·m): the commands as the driver turns them into a held voltage,
        with back-EMF compensation at the shaft speeds of ``x``."""
        if self.motor is None:
            return float(ul), float(ur)
        lim, top = self.i_tau, self.tau_max
        ul = lim if ul > lim else (-lim if ul < -lim else ul)
        ur = lim if ur > lim else (-lim if ur < -lim else ur)
        if self.compensates:
            w = x[PSD] - x[THD]
            h = self.b_r * x[ALD]
            ul += self.c_e * (w - h)
            ur += self.c_e * (w + h)
        return (top if ul > top else (-top if ul < -top else ul)), (top if ur > top else (-top if ur < -top else ur))

    # ---- dynamics ----------------------------------------------------------------------
    def f(self, t: float, s, u) -> np.ndarray:
        """ṡ (6,) for state ``s`` (6,) and motor torques τ_0 ``u`` = (τ_l, τ_r) in N·m."""
        return np.array(rhs(s, u[0], u[1], self.plant, NO_TAU)[:6])

    def step(self, s, tl: float, tr: float, periods: int = 1) -> np.ndarray:
        """State after ``periods`` control periods (classical RK4, :attr:`substeps` steps per
        period), τ_0 = (tl, tr) held."""
        dt = self.dt / self.substeps
        s = np.asarray(s, dtype=float)
        u = (tl, tr)
        for _ in range(periods * self.substeps):
            k1 = self.f(0.0, s, u)
            k2 = self.f(0.0, s + 0.5 * dt * k1, u)
            k3 = self.f(0.0, s + 0.5 * dt * k2, u)
            k4 = self.f(0.0, s + dt * k3, u)
            s = s + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return s

    def step6(self, s, command) -> np.ndarray:
        """State after one control period with the wheel torque commands ``command`` (N·m)."""
        tl, tr = self.delivered(s, command[0], command[1])
        return self.step(s, tl, tr)

    def perturbed(self, name: str, rel: float) -> "EstimatorModel":
        """The same model with parameter ``name`` (of :data:`twin.params.PARAMETER_DOCS`) times
        (1 + ``rel``); the motors' back-EMF damping stays added to d_b as it is."""
        p = self.params
        # n_xb kept as it is: a defaulted n_xb would follow n_yb (RobotParams.replace), a given
        # one (a log's robot) would not, and the pitch inertia's uncertainty is not the roll's
        changes = {"n_xb": p.n_xb, name: getattr(p, name) * (1.0 + rel)}
        return EstimatorModel(p.replace(**changes), self.motor, self.imu, self.encoders, 1.0 / self.dt)

    def sensitivity(self, names, s, command, periods: int = 1, base=None) -> np.ndarray:
        """(4, len(names)): how the synthetic IMU sample (ω_y, ω_z, f_x, f_z) of
        :meth:`synthetic_imu` moves per unit relative change of each parameter in ``names``
        (forward differences from ``base``, this model's sample at ``s``, computed if None; step
        :data:`SENSITIVITY_STEP`, a relative error of the result of about that size, which a
        variance model does not notice); units of the sample per 1."""
        cache = self.__dict__.setdefault("_perturbed", {})
        h = SENSITIVITY_STEP
        if base is None:
            base = self.synthetic_imu(s, command, periods)[0]
        out = np.empty((4, len(names)))
        for j, name in enumerate(names):
            model = cache.get(name)
            if model is None:
                model = cache[name] = self.perturbed(name, h)
            hi = model.synthetic_imu(s, command, periods)[0]
            for i in range(4):
                out[i, j] = (hi[i] - base[i]) / h
        return out

    def torque_sigma(self, tau: float) -> float:
        """σ (N·m) of the torque a motor delivers for the model's τ_0 = ``tau``."""
        return math.sqrt(self.sigma_tau ** 2 + (TORQUE_TOLERANCE * tau) ** 2)

    def synthetic_imu(self, s, command, periods: int = 1):
        """The IMU sample (means over the interval, as :mod:`twin.sensors.imu` defines them)
        equation (1) predicts for ``periods`` periods after state ``s`` with ``command``
        held, and the variance the model's torque uncertainty adds to it.

        Returns ((ω_y, ω_z, f_x, f_z), (gyro variance (rad/s)², accelerometer variance
        (m/s²)²)); the gyro readings are the true rates (no bias, no scale error).
        """
        tl, tr = self.delivered(s, command[0], command[1])
        s1 = self.step(s, tl, tr, periods)
        t = periods * self.dt
        th0, th1 = s[TH], s1[TH]
        xi, zi, r = self.xi, self.zi, self.r

        def point_velocity(st):
            # forward and vertical velocity of the IMU point in the heading frame
            sn, c = math.sin(st[TH]), math.cos(st[TH])
            dx, dz = xi * c + zi * sn, -xi * sn + zi * c
            return r * st[PSD] + st[THD] * dz, -st[THD] * dx, dx

        u0, w0, _ = point_velocity(s)
        u1, w1, dx1 = point_velocity(s1)
        ald = (s1[AL] - s[AL]) / t
        Fx = (u1 - u0) / t - ald * ald * dx1
        Fz = (w1 - w0) / t + self.g
        sn, c = math.sin(th1), math.cos(th1)
        fx, fz = Fx * c - Fz * sn, Fx * sn + Fz * c
        thm = (th1 - th0) / t
        # how one N·m on both wheels moves θ̈ and the IMU point's forward acceleration
        m11, m12, m22 = self.m11, self.m12, self.m22
        det = m11 * m22 - (m12 * c) ** 2
        dthdd = -(m11 + m12 * c) / det
        dpsdd = (m22 + m12 * c) / det
        var_tau = self.torque_sigma(tl) ** 2 + self.torque_sigma(tr) ** 2
        gyro_var = (0.5 * dthdd * t) ** 2 * var_tau
        accel_var = (r * dpsdd + zi * dthdd) ** 2 * var_tau
        return (thm, ald * math.cos(0.5 * (th0 + th1)), fx, fz), (gyro_var, accel_var)
