"""An example of one's own plant for mtwip-twin: the paper's Takagi–Sugeno model (equations
4–6, :mod:`twin.plant.ts_model`) as the robot, so a controller meets the very model it was
designed on. One file; a scenario names it as ``plant.model = "my_plant:TSPlant"``.

Run it (this directory on the path, or beside the scenario file, as here)::

    twin run examples/my_plant.toml

A plant meets :class:`twin.protocols.Plant` by having the right members: ``reset``, ``step``,
``close``, ``control_rate``, ``truth``, ``status`` and ``end_reason``. The twin builds it as
``TSPlant(config, theta0, alpha0, position, **plant.params)``: ``config`` is the scenario's
:class:`twin.plant.base.TwinConfig` (the true robot ``config.params``, the rates, the fall
angle), the start in rad, rad and (m, m). It gives no ``kinematics``, so it runs with ideal
sensing (``sensors.sensing = "ideal"``); its truth is checked at every step (it does not
declare ``trusted``).
"""
from __future__ import annotations

import math

from twin.plant.base import GroundTruth
from twin.plant.ts_model import rule1_weight, ts_matrices


class TSPlant:
    """x' = Σ m_i(θ) (A_i x + B_i u) on x = [θ, θ̇, ψ, ψ̇] (rad, rad/s), u = ul + ur (N·m),
    by RK4 with ``substeps`` steps per control period, the torques held over the period.

    The TS model has no heading: the robot drives straight at its initial heading, both wheels
    turning alike, and the axle midpoint moves r ψ along that heading from the start.
    """

    def __init__(self, config, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0), substeps: int = 5):
        if not (isinstance(substeps, int) and 1 <= substeps <= 1000):
            raise ValueError(f"substeps must be an integer from 1 to 1000, got {substeps!r}")
        self.params = config.params
        self.control_rate = float(config.control_rate)
        self.fall_angle = float(config.fall_angle)
        self.substeps = substeps
        (a1, a2), (b1, b2) = ts_matrices(self.params)
        self._rules = [(a.tolist(), [row[0] for row in b.tolist()]) for a, b in ((a1, b1), (a2, b2))]
        self.reset(theta0, alpha0, position)

    def reset(self, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0)) -> GroundTruth:
        """At rest at pitch ``theta0`` and heading ``alpha0`` (rad), axle midpoint ``position`` (m)."""
        self.x = [float(theta0), 0.0, 0.0, 0.0]
        self.alpha0 = float(alpha0)
        self.start = (float(position[0]), float(position[1]))
        self.n = 0
        self.status, self.end_reason = "running", ""
        self.truth = self._truth()
        return self.truth

    def step(self, ul: float, ur: float) -> GroundTruth:
        """Hold ``ul``, ``ur`` (N·m) for one control period."""
        if self.status != "running":
            raise RuntimeError(f"the run has ended ({self.status}); call reset()")
        u, h = float(ul) + float(ur), 1.0 / (self.control_rate * self.substeps)
        x = self.x
        for _ in range(self.substeps):
            k1 = self._f(x, u)
            k2 = self._f([x[i] + 0.5 * h * k1[i] for i in range(4)], u)
            k3 = self._f([x[i] + 0.5 * h * k2[i] for i in range(4)], u)
            k4 = self._f([x[i] + h * k3[i] for i in range(4)], u)
            x = [x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(4)]
        self.x = x
        self.n += 1
        self.truth = self._truth()
        if not all(map(math.isfinite, x)):
            self.status, self.end_reason = "diverged", f"the TS model's state is not finite at t = {self.truth.t:.3f} s"
        elif abs(x[0]) > self.fall_angle:
            self.status = "fell"
            self.end_reason = f"θ passed the fall limit {self.fall_angle:g} rad at t = {self.truth.t:.3f} s"
        return self.truth

    def close(self) -> None:
        if self.status == "running":
            self.status, self.end_reason = "closed", "the plant was closed"

    def _f(self, x, u: float) -> list[float]:
        """The TS model's x' (the two rules blended by their Nie–Tan weights)."""
        m1 = rule1_weight(x[0])
        out = [0.0, 0.0, 0.0, 0.0]
        for m, (a, b) in ((m1, self._rules[0]), (1.0 - m1, self._rules[1])):
            for i in range(4):
                out[i] += m * (a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2] + a[i][3] * x[3] + b[i] * u)
        return out

    def _truth(self) -> GroundTruth:
        th, th_d, psi, psi_d = self.x
        r, (x0, y0), a = self.params.r, self.start, self.alpha0
        return GroundTruth(self.n / self.control_rate, th, th_d, psi, psi, psi, psi_d, a, 0.0, r * psi,
                           x0 + r * psi * math.cos(a), y0 + r * psi * math.sin(a), 0.0, psi_d, psi_d)
