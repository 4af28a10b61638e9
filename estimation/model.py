"""What the estimator knows about the robot: equation (1), the motors' driver, the sensors.

State (9,), SI units::

    x = [θ, θ̇, ψ, ψ̇, α, α̇, b_y, b_z, c]

θ pitch (rad), ψ mean wheel angle (rad), α heading (rad) and their rates (rad/s); b_y,
b_z the gyro biases about the axle and the body's z axis (rad/s); c the encoders' zero:
an incremental encoder counts from power-up, so it reads q_i − q_i(0) = ψ_i − θ + c with
c = θ(0) (the wheels' angles from the vertical start at 0). c is constant and known only
as well as the initial tilt is.

Process (between control instants, the commands held): equation (1) with the nominal
parameters, driven by the torque each motor delivers. The driver of
:mod:`twin.actuators.dc_motor` sets its PWM duty from the command plus back-EMF
compensation at the shaft speed ω_k at the update, so over the period the motor delivers
τ_0 − c_e ω(t) with τ_0 = clip(τ*, current limit) + c_e ω_k clipped to the stall torque:
the back-EMF slope c_e acts exactly like extra body–wheel damping, so the model is
equation (1) with d_b + c_e and input τ_0 (computed from the estimated ω_k).

Measurements (see :mod:`twin.sensors`)::

    gyro     [ω_y, ω_z]   = [θ̇ + b_y, α̇ cos θ + b_z]
    accel    [f_x, f_z]   = specific force at the IMU point (x_i, z_i) in body axes:
                            with dx = x_i cos θ + z_i sin θ, dz = −x_i sin θ + z_i cos θ,
                            F_x = r ψ̈ + θ̈ dz − (θ̇² + α̇²) dx,  F_z = g − θ̈ dx − θ̇² dz,
                            f_x = F_x cos θ − F_z sin θ,  f_z = F_x sin θ + F_z cos θ
                            (ψ̈, θ̈ from equation (1) with the period's torques)
    encoders [ē, ẽ]       = [(e_l + e_r)/2, (e_r − e_l)/2] = [ψ − θ + c, (b/r)(α − α_0)]

Noise, all from the specifications:

* process: the PWM quantisation of each motor's torque (one duty step of the stall torque,
  uniform: σ = LSB/√12), held over the period; the gyro biases' random walk K²Δt.
* gyro: white σ = density/√Δt, the scale-factor tolerance times the rate, ADC LSB²/12.
* accel: the same, plus the torque quantisation's effect on ψ̈ and θ̈.
* encoders: one count, uniform: Δ²/12 per wheel (Δ²/24 for the mean and the half-difference).
"""
from __future__ import annotations

import math

import numpy as np

from twin.actuators.dc_motor import DCMotorParams
from twin.params import NOMINAL, RobotParams
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, EncoderSpec, ImuSpec

STATE_NAMES = ("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot", "gyro_bias_y", "gyro_bias_z",
               "encoder_zero")
STATE_UNITS = ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s", "rad/s", "rad/s", "rad")
N_STATES = 9
TH, THD, PS, PSD, AL, ALD, BY, BZ, C0 = range(N_STATES)


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
        self.m11, self.m12, self.m22, self.g_b, self.m33, self.n_bla = p.m11, p.m12, p.m22, p.g_b, p.m33, p.n_bla
        self.D = p.d_b + self.c_e  # body–wheel damping seen by the body: the drive's and the back-EMF's
        self.W = p.d_w
        self.Dy = (2.0 * p.b * p.b / (p.r * p.r)) * (self.D + self.W)
        self.b_r = p.b / p.r
        self.r, self.g = p.r, p.g
        self.xi, self.zi = imu.position[0], imu.position[2]
        if motor is None:
            self.tau_max = self.i_tau = math.inf
            self.sigma_tau = 0.0
            self.compensates = False
        else:
            self.tau_max = motor.stall_torque
            self.i_tau = motor.k_t * motor.max_current
            self.sigma_tau = motor.stall_torque / motor.pwm_steps / math.sqrt(12.0)
            self.compensates = motor.back_emf_compensation

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
    def accelerations(self, x, tl: float, tr: float) -> tuple[float, float, float]:
        """(θ̈, ψ̈, α̈) in rad/s² at state ``x`` with motor torques τ_0 ``tl``, ``tr`` (N·m)."""
        th, thd, psd, ald = x[TH], x[THD], x[PSD], x[ALD]
        s, c = math.sin(th), math.cos(th)
        m11, m12, m22, n = self.m11, self.m12, self.m22, self.n_bla
        drive = 2.0 * self.D * (thd - psd)
        u = tl + tr
        rhs1 = m12 * (thd * thd + ald * ald) * s - 2.0 * self.W * psd + drive + u
        rhs2 = n * ald * ald * s * c + self.g_b * s - drive - u
        det = m11 * m22 - (m12 * c) ** 2
        psdd = (m22 * rhs1 - m12 * c * rhs2) / det
        thdd = (m11 * rhs2 - m12 * c * rhs1) / det
        yaw = -2.0 * n * ald * thd * s * c - m12 * ald * psd * s - self.Dy * ald + self.b_r * (tr - tl)
        return thdd, psdd, yaw / (self.m33 + n * s * s)

    def f(self, t: float, x, u) -> np.ndarray:
        """ẋ (9,) for state ``x`` (9,) and motor torques τ_0 ``u`` = (τ_l, τ_r) N·m."""
        thdd, psdd, aldd = self.accelerations(x, u[0], u[1])
        return np.array([x[THD], thdd, x[PSD], psdd, x[ALD], aldd, 0.0, 0.0, 0.0])

    def step(self, x, tl: float, tr: float) -> np.ndarray:
        """State after one control period (classical RK4) with τ_0 = (tl, tr) held."""
        dt = self.dt
        x = np.asarray(x, dtype=float)
        u = (tl, tr)
        k1 = self.f(0.0, x, u)
        k2 = self.f(0.0, x + 0.5 * dt * k1, u)
        k3 = self.f(0.0, x + 0.5 * dt * k2, u)
        k4 = self.f(0.0, x + dt * k3, u)
        return x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def jacobians(self, x, tl: float, tr: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B): ∂ẋ/∂x (9, 9) and ∂ẋ/∂τ_0 (9, 2) at ``x`` with torques τ_0 = (tl, tr)."""
        th, thd, psd, ald = x[TH], x[THD], x[PSD], x[ALD]
        s, c = math.sin(th), math.cos(th)
        m11, m12, m22, n, D, W = self.m11, self.m12, self.m22, self.n_bla, self.D, self.W
        drive = 2.0 * D * (thd - psd)
        u = tl + tr
        rhs1 = m12 * (thd * thd + ald * ald) * s - 2.0 * W * psd + drive + u
        rhs2 = n * ald * ald * s * c + self.g_b * s - drive - u
        det = m11 * m22 - (m12 * c) ** 2
        psdd = (m22 * rhs1 - m12 * c * rhs2) / det
        thdd = (m11 * rhs2 - m12 * c * rhs1) / det
        # partial derivatives of rhs1, rhs2 by θ, θ̇, ψ̇, α̇
        r1 = (m12 * (thd * thd + ald * ald) * c, 2.0 * m12 * thd * s + 2.0 * D, -2.0 * W - 2.0 * D, 2.0 * m12 * ald * s)
        r2 = (n * ald * ald * (c * c - s * s) + self.g_b * c, -2.0 * D, 2.0 * D, 2.0 * n * ald * s * c)
        ddet = 2.0 * m12 * m12 * c * s
        A = np.zeros((N_STATES, N_STATES))
        A[TH, THD] = A[PS, PSD] = A[AL, ALD] = 1.0
        A[PSD, TH] = (m22 * r1[0] + m12 * s * rhs2 - m12 * c * r2[0] - psdd * ddet) / det
        A[THD, TH] = (m11 * r2[0] + m12 * s * rhs1 - m12 * c * r1[0] - thdd * ddet) / det
        for j, col in ((1, THD), (2, PSD), (3, ALD)):
            A[PSD, col] = (m22 * r1[j] - m12 * c * r2[j]) / det
            A[THD, col] = (m11 * r2[j] - m12 * c * r1[j]) / det
        J = self.m33 + n * s * s
        yaw = -2.0 * n * ald * thd * s * c - m12 * ald * psd * s - self.Dy * ald + self.b_r * (tr - tl)
        aldd = yaw / J
        A[ALD, TH] = (-2.0 * n * ald * thd * (c * c - s * s) - m12 * ald * psd * c - aldd * 2.0 * n * s * c) / J
        A[ALD, THD] = -2.0 * n * ald * s * c / J
        A[ALD, PSD] = -m12 * ald * s / J
        A[ALD, ALD] = (-2.0 * n * thd * s * c - m12 * psd * s - self.Dy) / J
        B = np.zeros((N_STATES, 2))
        B[PSD, :] = (m22 + m12 * c) / det
        B[THD, :] = -(m11 + m12 * c) / det
        B[ALD, 0], B[ALD, 1] = -self.b_r / J, self.b_r / J
        return A, B

    def _compensation(self, tl: float, tr: float) -> np.ndarray | None:
        """∂τ_0/∂x_k (2, 9): the driver's back-EMF compensation at the update-time speeds
        (zero for a wheel whose torque saturates), or None without compensation."""
        if not self.compensates:
            return None
        K = np.zeros((2, N_STATES))
        K[:, PSD] = self.c_e
        K[:, THD] = -self.c_e
        K[0, ALD], K[1, ALD] = -self.c_e * self.b_r, self.c_e * self.b_r
        for i, tq in enumerate((tl, tr)):
            if abs(tq) >= self.tau_max:
                K[i] = 0.0
        return K

    def transition(self, x, tl: float, tr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x⁺, F, G): the RK4 step of :meth:`step` and its exact derivatives by the state
        at the update (9, 9) and by the held torques τ_0 (9, 2), at ``x`` with τ_0.

        F includes that τ_0 depends on the shaft speeds at the update (the driver's
        back-EMF compensation). The derivatives follow the RK4 stages (the variational
        equation of the scheme): with the back-EMF the wheel rate's time constant is about
        two periods, too short for a Jacobian frozen over the period.
        """
        dt = self.dt
        x = np.asarray(x, dtype=float)
        u = (tl, tr)
        Kc = self._compensation(tl, tr)
        I = np.eye(N_STATES)
        xs, dxs, dus = x, I, np.zeros((N_STATES, 2))
        ks, dks, dkus = [], [], []
        for a in (0.0, 0.5, 0.5, 1.0):
            if ks:
                xs = x + (a * dt) * ks[-1]
                dxs = I + (a * dt) * dks[-1]
                dus = (a * dt) * dkus[-1]
            A, B = self.jacobians(xs, tl, tr)
            ks.append(self.f(0.0, xs, u))
            dk = A @ dxs
            if Kc is not None:
                dk = dk + B @ Kc
            dks.append(dk)
            dkus.append(A @ dus + B)
        w = dt / 6.0
        x_next = x + w * (ks[0] + 2.0 * ks[1] + 2.0 * ks[2] + ks[3])
        F = I + w * (dks[0] + 2.0 * dks[1] + 2.0 * dks[2] + dks[3])
        G = w * (dkus[0] + 2.0 * dkus[1] + 2.0 * dkus[2] + dkus[3])
        return x_next, F, G

    def process_noise(self, G: np.ndarray) -> np.ndarray:
        """Q (9, 9) for one period: torque quantisation through ``G`` and the bias random walk."""
        Q = (self.sigma_tau ** 2) * (G @ G.T)
        kg2 = self.imu.gyro.bias_random_walk ** 2 * self.dt
        Q[BY, BY] += kg2
        Q[BZ, BZ] += kg2
        return Q

    @property
    def imu_dt(self) -> float:
        return 1.0 / self.imu.rate

    # ---- measurements ------------------------------------------------------------------
    def gyro(self, x) -> np.ndarray:
        return np.array([x[THD] + x[BY], x[ALD] * math.cos(x[TH]) + x[BZ]])

    def gyro_jacobian(self, x) -> np.ndarray:
        H = np.zeros((2, N_STATES))
        H[0, THD] = H[0, BY] = 1.0
        H[1, TH] = -x[ALD] * math.sin(x[TH])
        H[1, ALD] = math.cos(x[TH])
        H[1, BZ] = 1.0
        return H

    def gyro_noise(self, x) -> np.ndarray:
        spec = self.imu.gyro
        w2 = spec.white_sigma(self.imu_dt) ** 2 + spec.lsb ** 2 / 12.0
        sf = spec.scale_factor_error
        return np.diag([w2 + (sf * x[THD]) ** 2, w2 + (sf * x[ALD]) ** 2])

    def accel(self, x, tl: float, tr: float) -> np.ndarray:
        """[f_x, f_z] (m/s²) at ``x`` with the period's torques τ_0 = (tl, tr)."""
        return np.array(self._accel(x, tl, tr))

    def _accel(self, x, tl, tr):
        th, thd, ald = x[TH], x[THD], x[ALD]
        thdd, psdd, _ = self.accelerations(x, tl, tr)
        s, c = math.sin(th), math.cos(th)
        dx = self.xi * c + self.zi * s
        dz = -self.xi * s + self.zi * c
        Fx = self.r * psdd + thdd * dz - (thd * thd + ald * ald) * dx
        Fz = self.g - thdd * dx - thd * thd * dz
        return Fx * c - Fz * s, Fx * s + Fz * c

    def accel_jacobian(self, x, tl: float, tr: float) -> tuple[np.ndarray, np.ndarray]:
        """(H (2, 9), H_u (2, 2)): ∂[f_x, f_z]/∂x and ∂[f_x, f_z]/∂τ_0."""
        th, thd, ald = x[TH], x[THD], x[ALD]
        A, B = self.jacobians(x, tl, tr)
        thdd, psdd, _ = self.accelerations(x, tl, tr)
        s, c = math.sin(th), math.cos(th)
        xi, zi, r = self.xi, self.zi, self.r
        dx = xi * c + zi * s
        dz = -xi * s + zi * c
        Fx = r * psdd + thdd * dz - (thd * thd + ald * ald) * dx
        Fz = self.g - thdd * dx - thd * thd * dz
        dFx = r * A[PSD] + dz * A[THD]
        dFz = -dx * A[THD]
        # dx/dθ = dz, dz/dθ = −dx
        dFx[TH] += -thdd * dx - (thd * thd + ald * ald) * dz
        dFz[TH] += -thdd * dz + thd * thd * dx
        dFx[THD] += -2.0 * thd * dx
        dFx[ALD] += -2.0 * ald * dx
        dFz[THD] += -2.0 * thd * dz
        H = np.empty((2, N_STATES))
        H[0] = c * dFx - s * dFz
        H[1] = s * dFx + c * dFz
        H[0, TH] += -s * Fx - c * Fz
        H[1, TH] += c * Fx - s * Fz
        uFx = r * B[PSD] + dz * B[THD]
        uFz = -dx * B[THD]
        Hu = np.vstack([c * uFx - s * uFz, s * uFx + c * uFz])
        return H, Hu

    def accel_noise(self, z_pred, Hu) -> np.ndarray:
        spec = self.imu.accel
        w2 = spec.white_sigma(self.imu_dt) ** 2 + spec.lsb ** 2 / 12.0
        sf = spec.scale_factor_error
        R = np.diag([w2 + (sf * z_pred[0]) ** 2, w2 + (sf * z_pred[1]) ** 2])
        return R + (self.sigma_tau ** 2) * (Hu @ Hu.T)

    def encoders_h(self, x, alpha0: float) -> np.ndarray:
        return np.array([x[PS] - x[TH] + x[C0], self.b_r * (x[AL] - alpha0)])

    def encoders_jacobian(self) -> np.ndarray:
        H = np.zeros((2, N_STATES))
        H[0, PS] = H[0, C0] = 1.0
        H[0, TH] = -1.0
        H[1, AL] = self.b_r
        return H

    def encoders_noise(self) -> np.ndarray:
        q = self.encoders.resolution ** 2 / 24.0
        return np.diag([q, q])
