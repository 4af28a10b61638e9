"""An example of one's own controller and estimator for mtwip-twin, outside the package.

Run it (this directory on the path, or `pip install`-ed as your own package):

    twin run paper-exp3 --controller my_plugins:StateFeedback --set sensors.estimator='"my_plugins:TiltFilter"'

Both classes meet the protocols of ``twin.protocols`` by having the right methods; they
import nothing from the twin.
"""
from __future__ import annotations

import math


class StateFeedback:
    """u = −K [θ, θ̇, ψ_e, ψ̇] on the balance, u_α = −K_α [α − α_d, α̇] on the heading.

    ``k`` the four balance gains (N·m/rad, N·m·s/rad, N·m/rad, N·m·s/rad), ``k_heading``
    the two heading gains (N·m/rad, N·m·s/rad), ``wheel_radius`` m, ``psi_error_limit``
    rad: the wheel-angle error towards a position target is clipped to ± this, so that a
    distant target does not become a huge torque. The default balance gains are about the
    LMI design's upright-rule gains (twin design), the heading gains the LQR's.
    """

    signals = ("u", "u_alpha")  # extra signals logged with the run, after (ul, ur)
    signal_units = {"u": "N·m", "u_alpha": "N·m"}

    def __init__(self, k=(-1.2, -0.085, -0.06, -0.032), k_heading=(0.090932, 0.058746),
                 wheel_radius: float = 0.04, psi_error_limit: float = 1.0):
        if len(k) != 4 or len(k_heading) != 2:
            raise ValueError("k needs 4 gains and k_heading 2")
        self.k = tuple(float(v) for v in k)
        self.k_heading = tuple(float(v) for v in k_heading)
        self.r = float(wheel_radius)
        self.limit = float(psi_error_limit)

    def reset(self, targets) -> None:
        """Nothing to forget: a static state feedback."""

    def __call__(self, estimate, targets):
        theta, theta_dot, psi, psi_dot, alpha, alpha_dot = estimate
        p_d, alpha_d = targets
        psi_e = psi if p_d is None else min(self.limit, max(-self.limit, psi - p_d / self.r))
        k = self.k
        u = -(k[0] * theta + k[1] * theta_dot + k[2] * psi_e + k[3] * psi_dot)
        u_alpha = 0.0
        if alpha_d is not None:
            u_alpha = -(self.k_heading[0] * (alpha - alpha_d) + self.k_heading[1] * alpha_dot)
        return (0.5 * u - u_alpha, 0.5 * u + u_alpha, u, u_alpha)


class TiltFilter:
    """A complementary filter for θ and wheel odometry for ψ and α.

    θ ← a (θ + ω_y Δt) + (1 − a) atan2(−f_x, f_z); θ̇ the gyro's pitch rate; ψ the mean
    encoder angle plus θ; α from the encoders' difference; ψ̇ by the difference over the last
    ``window`` periods (over one, the encoders' counts make it jump by a count per period: a
    controller with a speed gain then chatters).
    ``context`` (given by the twin because the signature asks for it) supplies the
    control period, the wheel radius and half-track, and the initial heading.
    """

    def __init__(self, context, a: float = 0.98, window: int = 4):
        self.dt = 1.0 / context.control_rate
        self.window = int(window)
        self.r_b = context.model.r / context.model.b
        self.alpha0 = context.alpha0
        self.a = float(a)

    def start(self, m):
        fx, _, fz = m.accel
        self.theta = math.atan2(-fx, fz)
        self.theta0 = self.theta
        self.rate = (m.gyro[1], m.gyro[2])
        self.enc = tuple(m.encoders) if m.encoders is not None else (0.0, 0.0)
        self.psi_hist = []
        return self._output()

    def step(self, m, command):
        if m.gyro is not None and all(map(math.isfinite, m.gyro)):
            self.rate = (m.gyro[1], m.gyro[2])
        pred = self.theta + self.rate[0] * self.dt
        if m.accel is not None and all(map(math.isfinite, m.accel)):
            pred = self.a * pred + (1.0 - self.a) * math.atan2(-m.accel[0], m.accel[2])
        self.theta = pred
        if m.encoders is not None and all(map(math.isfinite, m.encoders)):
            self.enc = tuple(m.encoders)
        return self._output()

    def _output(self):
        el, er = self.enc
        psi = 0.5 * (el + er) + self.theta - self.theta0
        alpha = self.alpha0 + self.r_b * 0.5 * (er - el)
        hist = self.psi_hist
        hist.append(psi)
        if len(hist) > self.window + 1:
            del hist[0]
        psi_dot = (hist[-1] - hist[0]) / ((len(hist) - 1) * self.dt) if len(hist) > 1 else 0.0
        return (self.theta, self.rate[0], psi, psi_dot, alpha, self.rate[1] / max(math.cos(self.theta), 0.1))

    def stats(self) -> dict:
        return {"rejected_total": 0}
