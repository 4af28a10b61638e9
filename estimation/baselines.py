"""Two estimators hobby balance bots use, as baselines for :class:`estimation.ekf.EKFEstimator`.

Both estimate θ from the gyro's pitch rate and the accelerometer's direction of gravity,
θ_acc = atan2(−f_x, f_z), as a tilt sensor would: they do not model the robot's own
acceleration, which is what a balancing robot is doing all the time. They take the
samples as they arrive (no latency handling). Their settings are the published ones,
not tuned here, so that they are neither helped nor handicapped:

* :class:`ComplementaryFilter`: θ ← a (θ + ω Δt) + (1 − a) θ_acc with a = 0.98, the value
  of the widely copied tutorials (a time constant of a Δt / (1 − a) = 0.245 s at 200 Hz).
* :class:`AngleBiasKalman`: the two-state (angle, gyro bias) Kalman filter of TKJ
  Electronics' ``KalmanFilter`` library (K. S. Lauszus, 2012), ported line for line,
  with its defaults Q_angle = 0.001, Q_bias = 0.003, R_measure = 0.03 in its own units
  (degrees, degrees per second).

For the rest of the controllers' state both use what such a robot does: odometry from
the encoders (ψ = ē + θ − θ(0), α = α_0 + (r/b) ẽ), the wheel rate as the change of ψ
over the last four periods, the yaw rate from the gyro (ω_z / cos θ).

Innovations (the optional ``diagnostics()`` hook of :class:`twin.protocols.Estimator`): the
two-state Kalman filter reports its accelerometer-angle update's innovation and its
covariance, converted from its degrees to rad; the complementary filter has no covariance,
so no normalised innovation to report, and has no ``diagnostics()`` at all.
"""
from __future__ import annotations

import math

from estimation.ekf import Estimate, finite_reading
from twin.errors import TwinError

_DEG = 180.0 / math.pi
_SPEED_WINDOW = 4  # control periods over which the wheel rate is differenced


class _TiltBaseline:
    """Shared start-up, odometry and sample handling."""

    name = "baseline"

    def __init__(self, control_rate: float, wheel_radius: float, half_track: float, alpha0: float = 0.0):
        self.dt = 1.0 / float(control_rate)
        self.r_b = wheel_radius / half_track
        self.alpha0 = float(alpha0)
        self.k = -1
        self.theta0 = 0.0
        self._gyro = (0.0, 0.0, 0.0)
        self._enc = (0.0, 0.0)
        self._psi_hist: list[float] = []
        self.rejected_total = 0  # no gating: nothing is ever rejected
        self.periods = "constant"  # see set_sampling
        self._nominal_dt = self.dt
        self._t_hist: list[float] = []  # periods = "rows": the instants' times (s) of _psi_hist

    def set_sampling(self, imu: str = "mean", commands: str = "held", periods: str = "constant") -> None:
        """How a log's rows were sampled (:meth:`twin.protocols.Estimator` optional hook). These
        filters take every IMU row as the rate at its instant and need no command, so ``imu`` and
        ``commands`` change nothing; ``periods = "rows"`` (a log whose instants are its rows, not
        on a regular grid): each step integrates over the time since the previous measurement's
        ``t`` instead of 1 / control rate."""
        if periods not in ("constant", "rows"):
            raise TwinError(f"periods must be \"constant\" or \"rows\", got {periods!r}")
        self.periods = periods

    def stats(self) -> dict:
        return {"rejected_total": 0}

    @staticmethod
    def accel_angle(accel) -> float:
        return math.atan2(-accel[0], accel[2])

    def _new_run(self) -> None:
        """The state of one run, as before the first start() (start() calls it for a second run)."""
        self.k = -1
        self.theta0 = 0.0
        self._gyro = (0.0, 0.0, 0.0)
        self._enc = (0.0, 0.0)
        self._psi_hist = []
        self._t_hist = []
        self.dt = self._nominal_dt

    def start(self, meas) -> Estimate:
        if self.k >= 0:  # a second run with the same filter: forget the first
            self._new_run()
        if meas.accel is None:
            raise TwinError(f"the {self.name} estimator needs an accelerometer reading at start")
        self.theta0 = self.accel_angle(meas.accel)
        self._init_angle(self.theta0)
        self.k = 0
        self._t = float(meas.t)
        if meas.gyro is not None:
            self._gyro = meas.gyro
        return self._output(meas)

    def step(self, meas, command=None) -> Estimate:
        if self.k < 0:
            raise TwinError("call start() with the first measurement before step()")
        self.k += 1
        if self.periods == "rows":  # this step spans the time since the last instant
            t = float(meas.t)
            if not t > self._t:
                raise TwinError(f"instants must be strictly increasing in time; got t = {t!r} s after {self._t!r} s")
            self.dt, self._t = t - self._t, t
        ok = finite_reading
        if ok(meas.gyro):
            self._gyro = meas.gyro  # a missing sample: the last one is used again
        self._filter(self._gyro[1], self.accel_angle(meas.accel) if ok(meas.accel) else None)
        if ok(meas.encoders):
            self._enc = meas.encoders
        return self._output(meas)

    def _output(self, meas) -> Estimate:
        theta, theta_dot = self.angle_and_rate()
        el, er = self._enc
        psi = 0.5 * (el + er) + theta - self.theta0
        hist = self._psi_hist
        hist.append(psi)
        if len(hist) > _SPEED_WINDOW + 1:
            del hist[0]
        if self.periods == "rows":
            th = self._t_hist
            th.append(float(meas.t))
            if len(th) > _SPEED_WINDOW + 1:
                del th[0]
            psi_dot = (hist[-1] - hist[0]) / (th[-1] - th[0]) if len(hist) > 1 else 0.0
        else:
            psi_dot = (hist[-1] - hist[0]) / ((len(hist) - 1) * self.dt) if len(hist) > 1 else 0.0
        alpha = self.alpha0 + self.r_b * 0.5 * (er - el)
        c = math.cos(theta)
        alpha_dot = self._gyro[2] / c if abs(c) > 0.1 else 0.0
        return Estimate(theta, theta_dot, psi, psi_dot, alpha, alpha_dot)


class ComplementaryFilter(_TiltBaseline):
    """θ ← a (θ + ω_y Δt) + (1 − a) θ_acc; θ̇ is the raw gyro rate."""

    name = "complementary"

    def __init__(self, control_rate: float, wheel_radius: float, half_track: float, alpha0: float = 0.0,
                 a: float = 0.98):
        super().__init__(control_rate, wheel_radius, half_track, alpha0)
        if not (0.0 <= a < 1.0):
            raise TwinError(f"complementary filter coefficient a must be in [0, 1), got {a!r}")
        self.a = float(a)
        self.theta = 0.0

    def _new_run(self) -> None:
        super()._new_run()
        self.theta = 0.0

    def _init_angle(self, theta: float) -> None:
        self.theta = theta

    def _filter(self, rate: float, theta_acc) -> None:
        pred = self.theta + rate * self.dt
        self.theta = pred if theta_acc is None else self.a * pred + (1.0 - self.a) * theta_acc

    def angle_and_rate(self):
        return self.theta, self._gyro[1]


class AngleBiasKalman(_TiltBaseline):
    """TKJ Electronics' two-state Kalman filter (angle in degrees, gyro bias in °/s)."""

    name = "kalman2"

    def __init__(self, control_rate: float, wheel_radius: float, half_track: float, alpha0: float = 0.0,
                 q_angle: float = 0.001, q_bias: float = 0.003, r_measure: float = 0.03):
        super().__init__(control_rate, wheel_radius, half_track, alpha0)
        self.Q_angle, self.Q_bias, self.R_measure = float(q_angle), float(q_bias), float(r_measure)
        self._new_run()

    def _new_run(self) -> None:
        super()._new_run()
        self.angle = 0.0  # degrees
        self.bias = 0.0  # degrees per second
        self.rate = 0.0
        self.P = [[0.0, 0.0], [0.0, 0.0]]
        self._innov = None  # the last step's update (y, S) in degrees and degrees², None: no update

    def _init_angle(self, theta: float) -> None:
        self.angle = theta * _DEG

    def _filter(self, rate: float, theta_acc) -> None:
        # Kalman::getAngle(newAngle, newRate, dt), with the update skipped without an angle
        dt, P = self.dt, self.P
        self._innov = None
        self.rate = rate * _DEG - self.bias
        self.angle += dt * self.rate
        P[0][0] += dt * (dt * P[1][1] - P[0][1] - P[1][0] + self.Q_angle)
        P[0][1] -= dt * P[1][1]
        P[1][0] -= dt * P[1][1]
        P[1][1] += self.Q_bias * dt
        if theta_acc is None:
            return
        S = P[0][0] + self.R_measure
        K0, K1 = P[0][0] / S, P[1][0] / S
        y = theta_acc * _DEG - self.angle
        self._innov = (y, S)
        self.angle += K0 * y
        self.bias += K1 * y
        P00, P01 = P[0][0], P[0][1]
        P[0][0] -= K0 * P00
        P[0][1] -= K0 * P01
        P[1][0] -= K1 * P00
        P[1][1] -= K1 * P01

    def angle_and_rate(self):
        return self.angle / _DEG, self.rate / _DEG

    def diagnostics(self) -> dict:
        """The :class:`twin.protocols.Estimator` hook about the last step: where the
        accelerometer angle updated the filter, its ``innovation`` (1,) rad (θ_acc less the
        predicted angle) and ``innovation_cov`` (1, 1) rad² (P₀₀ + R_measure, the library's
        own belief), with ``nis`` = y²/S and ``nis_dof`` 1; else ``nis`` NaN, ``nis_dof`` 0."""
        if self._innov is None:
            return {"nis": math.nan, "nis_dof": 0}
        y, S = self._innov
        return {"nis": y * y / S, "nis_dof": 1, "innovation": [y / _DEG], "innovation_cov": [[S / _DEG ** 2]]}
