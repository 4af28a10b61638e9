"""The twin's state estimator: an extended Kalman filter (filterpy) of θ, ψ, α, their
rates, the gyro biases and the encoders' zero, with gated updates and latency handling.

Why an EKF and not a UKF. The process is equation (1) over one 5 ms period, in which
the state moves little: linearising it there costs an error of order (ω Δt)² with
ω ≈ 12 rad/s the body's unstable pole, far below the process noise; the measurement
models are smooth (sines of θ and quadratic rates). A UKF would need 19 sigma points,
each through an RK4 step and the accelerometer model, for no measurable gain; the
analytic Jacobians of :mod:`estimation.model` are cheap and tested against finite
differences.

One control step (:meth:`EKFEstimator.step`)
    1. The filter runs L = max(IMU latency, encoder latency) periods behind: it predicts
       to t_{k−L} with the command applied then, and updates with the samples taken at
       t_{k−L}, which arrive now. Predict-only when a sensor delivers nothing (dropouts).
    2. Each sensor's update (gyro, accelerometer, encoders: 2 values each) is gated: its
       normalised innovation squared ε = yᵀ S⁻¹ y is compared with the χ²(2) quantile at
       1 − ``gate_probability``; a failing measurement is rejected and counted. After
       ``max_rejects_in_row`` rejections in a row a sensor's next update is accepted
       (logged): the filter re-synchronises rather than coasting forever.
    3. The estimate handed to the controllers is the filter's state predicted forward
       the L periods with the commands since (no measurement is that fresh).
    A non-finite state or covariance never leaves: the last good estimate is restored
    with its covariance inflated, and the reason is logged in :attr:`events`.

filterpy's textbook names are kept: x, P, F, Q, H, R, y (innovation), S, K and the
likelihood of the last update are attributes of :attr:`EKFEstimator.kf`.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from estimation.model import AL, BY, BZ, C0, N_STATES, PS, PSD, TH, THD, ALD, EstimatorModel
from twin.errors import TwinError

GROUPS = ("gyro", "accel", "encoders")


class Estimate(NamedTuple):
    """The controllers' state [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s) at one control instant."""

    theta: float
    theta_dot: float
    psi: float
    psi_dot: float
    alpha: float
    alpha_dot: float


class TwinEKF(ExtendedKalmanFilter):
    """filterpy's EKF with equation (1) as its nonlinear prediction."""

    def __init__(self, model: EstimatorModel):
        super().__init__(dim_x=N_STATES, dim_z=2, dim_u=2)
        self.model = model
        self.x = np.zeros(N_STATES)

    def predict(self, u=(0.0, 0.0)):
        """Prior for the next control instant with the motor torques τ_0 = ``u`` (N·m) held:
        F and Q are linearised at the current x, then filterpy's predict runs."""
        self._x_next, self.F, G = self.model.transition(self.x, u[0], u[1])
        self.Q = self.model.process_noise(G)
        super().predict(u)

    def predict_x(self, u=(0.0, 0.0)):
        """x ← the RK4 step of equation (1) (computed with F in :meth:`predict`)."""
        self.x = self._x_next

    def nis(self, z, H, hx, R) -> tuple[float, np.ndarray]:
        """(ε, S): the normalised innovation squared of measurement ``z`` before updating."""
        y = np.asarray(z, float) - hx
        S = H @ self.P @ H.T + R
        return float(y @ np.linalg.solve(S, y)), S


class EKFEstimator:
    """State estimation for the controllers from the twin's sensor readings.

    Parameters
    ----------
    model : EstimatorModel
        What the filter assumes (nominal robot, motor and sensor specifications).
    imu_every : int
        Control periods per IMU sample.
    imu_latency, encoder_latency : int
        Nominal latencies in control periods (the filter assumes these).
    alpha0 : float
        The heading the encoders' odometry starts from (rad).
    gate_probability : float
        Probability that the gate rejects a measurement that fits the model.
    max_rejects_in_row : int
        See the module docstring.
    """

    name = "ekf"

    def __init__(self, model: EstimatorModel, imu_every: int = 1, imu_latency: int = 1, encoder_latency: int = 0,
                 alpha0: float = 0.0, gate_probability: float = 1e-4, max_rejects_in_row: int = 40):
        if not (0.0 < gate_probability < 0.5):
            raise TwinError(f"gate_probability must be in (0, 0.5), got {gate_probability!r}")
        self.model = model
        self.kf = TwinEKF(model)
        self.imu_every, self.d_imu, self.d_enc = int(imu_every), int(imu_latency), int(encoder_latency)
        self.lag = max(self.d_imu, self.d_enc)
        self.alpha0 = float(alpha0)
        self.gate = float(chi2.ppf(1.0 - gate_probability, 2))
        self.max_rejects_in_row = int(max_rejects_in_row)
        self.k = -1
        self.m = 0  # the filter's step index (it runs ``lag`` periods behind)
        self._commands: dict[int, tuple[float, float]] = {}
        self._imu: dict[int, tuple] = {}
        self._enc: dict[int, tuple] = {}
        self._torque = (0.0, 0.0)  # τ_0 acting just before the filter's time
        self.accepted = dict.fromkeys(GROUPS, 0)
        self.rejected = dict.fromkeys(GROUPS, 0)
        self.in_row = dict.fromkeys(GROUPS, 0)
        self.last_nis = dict.fromkeys(GROUPS, math.nan)
        self.predict_only = 0
        self.events: list[tuple[float, str]] = []
        self.resets = 0

    # ---- public -----------------------------------------------------------------------
    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    @property
    def x(self) -> np.ndarray:
        """The filter's state (9,) at its own time t_{k−lag}."""
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    def stats(self) -> dict:
        return {"accepted": dict(self.accepted), "rejected": dict(self.rejected),
                "rejected_total": self.rejected_total, "predict_only_steps": self.predict_only,
                "resets": self.resets, "events": [f"t = {t:.3f} s: {why}" for t, why in self.events]}

    def start(self, meas) -> Estimate:
        """Initialise from the first readings, the robot at rest (control step 0).

        θ from the accelerometer's direction of gravity; rates 0; ψ 0 (the twin's wheel
        angles start at 0); the encoders' zero c = θ, exactly as uncertain as θ; gyro
        biases 0 with the turn-on σ of the specification.
        """
        if meas.accel is None or not all(math.isfinite(v) for v in meas.accel):
            raise TwinError("the estimator needs an accelerometer reading at start to find the initial tilt")
        m = self.model
        fx, _, fz = meas.accel
        theta0 = math.atan2(-fx, fz)
        g = math.hypot(fx, fz)
        spec_a, spec_g = m.imu.accel, m.imu.gyro
        var_theta = (spec_a.white_sigma(m.imu_dt) ** 2 + spec_a.turn_on_bias ** 2
                     + (spec_a.scale_factor_error * g) ** 2 * 0.5) / max(g, 1.0) ** 2
        x = np.zeros(N_STATES)
        x[TH] = x[C0] = theta0
        x[AL] = self.alpha0
        P = np.diag([var_theta, 1e-8, 1e-10, 1e-8, 1e-10, 1e-8, spec_g.turn_on_bias ** 2 + 1e-10,
                     spec_g.turn_on_bias ** 2 + 1e-10, var_theta])
        P[TH, C0] = P[C0, TH] = var_theta * (1.0 - 1e-9)
        self.kf.x, self.kf.P = x, P
        self.k, self.m = 0, 0
        self._store(meas, 0)
        self._good = (x.copy(), P.copy())
        return self._estimate(x)

    def step(self, meas, command) -> Estimate:
        """Advance to the next control instant.

        ``meas``: the :class:`twin.sensors.Measurement` that arrived now; ``command``:
        the wheel torque commands (ul, ur) in N·m applied over the period that just ended.
        """
        if self.k < 0:
            raise TwinError("call start() with the first measurement before step()")
        k = self.k = self.k + 1
        self._commands[k - 1] = (float(command[0]), float(command[1]))
        self._store(meas, k)
        m_target = k - self.lag
        kf = self.kf
        try:
            if m_target >= 1:
                self._predict(self._commands.get(m_target - 1, (0.0, 0.0)))
                self.m = m_target
            if m_target >= 0:
                used = self._update_at(m_target, meas.t - self.lag * self.model.dt)
                if not used:
                    self.predict_only += 1
            self._check_finite(meas.t)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError) as err:
            self._restore(meas.t, f"numerical failure in the filter ({err}); restored the last good estimate")
        # forget what the filter has passed
        for d in (self._commands, self._imu, self._enc):
            for old in [j for j in d if j < self.m - 1]:
                del d[old]
        return self._estimate(self._forward(kf.x, self.m, k))

    # ---- internals ---------------------------------------------------------------------
    def _store(self, meas, k: int) -> None:
        ok = lambda v: v is not None and all(math.isfinite(c) for c in v)  # noqa: E731
        bad = [n for n, v in (("gyro", meas.gyro), ("accel", meas.accel), ("encoders", meas.encoders))
               if v is not None and not ok(v)]
        for n in bad:
            self.events.append((meas.t, f"non-finite {n} reading ignored"))
        if ok(meas.gyro) and ok(meas.accel):
            self._imu[k - self.d_imu] = (meas.gyro, meas.accel)
        elif ok(meas.gyro) or ok(meas.accel):
            self._imu[k - self.d_imu] = (meas.gyro if ok(meas.gyro) else None,
                                         meas.accel if ok(meas.accel) else None)
        if ok(meas.encoders):
            self._enc[k - self.d_enc] = meas.encoders

    def _predict(self, command) -> None:
        kf, model = self.kf, self.model
        tau = model.delivered(kf.x, command[0], command[1])
        kf.predict(u=tau)
        self._torque = tau

    def _update_at(self, m: int, t: float) -> bool:
        kf, model = self.kf, self.model
        used = False
        imu = self._imu.get(m)
        if imu is not None:
            gyro, accel = imu
            if gyro is not None:
                z = (gyro[1], gyro[2])
                H = model.gyro_jacobian(kf.x)
                used |= self._gated("gyro", z, H, model.gyro(kf.x), model.gyro_noise(kf.x), t)
            if accel is not None:
                z = (accel[0], accel[2])
                tl, tr = self._torque
                H, Hu = model.accel_jacobian(kf.x, tl, tr)
                hx = model.accel(kf.x, tl, tr)
                used |= self._gated("accel", z, H, hx, model.accel_noise(hx, Hu), t, (tl, tr))
        enc = self._enc.get(m)
        if enc is not None:
            z = (0.5 * (enc[0] + enc[1]), 0.5 * (enc[1] - enc[0]))
            used |= self._gated("encoders", z, model.encoders_jacobian(), model.encoders_h(kf.x, self.alpha0),
                                model.encoders_noise(), t)
        if used:
            kf.P = 0.5 * (kf.P + kf.P.T)
        return used

    def _gated(self, group: str, z, H, hx, R, t: float, torque=None) -> bool:
        kf = self.kf
        eps, _ = kf.nis(z, H, hx, R)
        self.last_nis[group] = eps
        if not (eps <= self.gate):
            if self.in_row[group] < self.max_rejects_in_row:
                self.rejected[group] += 1
                self.in_row[group] += 1
                return False
            self.events.append((t, f"{group} accepted after {self.in_row[group]} rejections in a row "
                                   f"(NIS {eps:.3g} > gate {self.gate:.3g}): re-synchronising"))
        self.in_row[group] = 0
        kf.update(np.asarray(z, float), lambda x, H=H: H, lambda x, hx=hx: hx, R=R)
        self.accepted[group] += 1
        return True

    def _check_finite(self, t: float) -> None:
        kf = self.kf
        if np.isfinite(kf.x).all() and np.isfinite(kf.P).all() and (np.diag(kf.P) > 0).all():
            self._good = (kf.x.copy(), kf.P.copy())
        else:
            self._restore(t, "the state or covariance became non-finite or lost positivity; "
                             "restored the last good estimate")

    def _restore(self, t: float, why: str) -> None:
        x, P = self._good
        self.kf.x, self.kf.P = x.copy(), 4.0 * P + np.diag(np.full(N_STATES, 1e-8))
        self.resets += 1
        self.events.append((t, why))

    def _forward(self, x: np.ndarray, m: int, k: int) -> np.ndarray:
        """The filter's state at t_m predicted to t_k with the commands in between."""
        model = self.model
        for j in range(m, k):
            cmd = self._commands.get(j, (0.0, 0.0))
            tau = model.delivered(x, cmd[0], cmd[1])
            x = model.step(x, tau[0], tau[1])
        if not np.isfinite(x).all():
            self.events.append((k * model.dt, "forward prediction non-finite; handing out the filter's own state"))
            x = self._good[0]
        return x

    @staticmethod
    def _estimate(x) -> Estimate:
        return Estimate(float(x[TH]), float(x[THD] ), float(x[PS]), float(x[PSD]), float(x[AL]), float(x[ALD]))


__all__ = ["EKFEstimator", "Estimate", "TwinEKF", "GROUPS", "BY", "BZ"]
