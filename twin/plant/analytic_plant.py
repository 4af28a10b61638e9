"""Equation (1) as a :class:`twin.protocols.Plant`: the analytic model in the same closed loop
as the PyBullet twin (``plant.model = "analytic"``).

The state [θ, θ̇, ψ, ψ̇, α, α̇, X, Y] (:mod:`twin.plant.analytic`) is integrated with
fixed-step RK4 at the physics rate, the wheel torques held over each control period (a
zero-order hold, as on the robot's microcontroller). The torques are ideal sources: the
commands are delivered exactly (``config.motor`` is not used). There is no contact model:
the wheels roll without slip on a level floor, so a config with a slope, other friction,
pushes, a payload or a centre-of-mass offset is refused (those need the PyBullet twin).

Ground truth as the twin's: ψ_l, ψ_r = ψ ∓ (b / r)(α − α0) by rolling without slip from
the start, roll 0, distance r ψ, (X, Y) the axle midpoint. The run ends as ``"fell"``
when |θ| passes ``config.fall_angle`` and as ``"diverged"`` on a non-finite state.

For the simulated IMU the body's pose and velocity are built from the planar state
(:func:`planar_kinematics`), so the sensors and the EKF run on this plant as on the twin.
"""
from __future__ import annotations

import math

import numpy as np

from twin.errors import TwinError
from twin.plant.analytic import STATE_NAMES, rk4_step
from twin.plant.base import Actuation, GroundTruth, TwinConfig, checked_start
from twin.plant.disturbances import Disturbances, Ground

_ZERO3 = (0.0, 0.0, 0.0)


def planar_kinematics(theta: float, theta_dot: float, alpha: float, alpha_dot: float, v_axle: float,
                      axle, com_local):
    """The body's pose and velocity in PyBullet's layout (see :class:`twin.protocols.Plant`'s
    ``kinematics``) for a robot on a level floor: pitch ``theta`` (rad) about the axle, heading
    ``alpha`` (rad), their rates (rad/s), the axle midpoint's speed ``v_axle`` (m/s, along the
    heading) and position ``axle`` (x, y, z) m, the centre of mass ``com_local`` (3,) m in body
    axes from the axle midpoint. The orientation is R = Rz(α) Ry(θ) (no roll)."""
    sa, ca = math.sin(0.5 * alpha), math.cos(0.5 * alpha)
    st, ct = math.sin(0.5 * theta), math.cos(0.5 * theta)
    quat = (-sa * st, ca * st, sa * ct, ca * ct)  # qz(α) ⊗ qy(θ), (x, y, z, w)
    s, c = math.sin(theta), math.cos(theta)
    sA, cA = math.sin(alpha), math.cos(alpha)
    # R = Rz(α) Ry(θ) as rows
    R = ((cA * c, -sA, cA * s), (sA * c, cA, sA * s), (-s, 0.0, c))
    cx, cy, cz = com_local
    d = tuple(R[i][0] * cx + R[i][1] * cy + R[i][2] * cz for i in range(3))
    w = (-sA * theta_dot, cA * theta_dot, alpha_dot)  # α̇ ẑ + θ̇ (the axle's direction)
    v = (v_axle * cA + w[1] * d[2] - w[2] * d[1], v_axle * sA + w[2] * d[0] - w[0] * d[2], w[0] * d[1] - w[1] * d[0])
    com = (axle[0] + d[0], axle[1] + d[1], axle[2] + d[2])
    return (com, quat), (v, w)


class AnalyticPlant:
    """Equation (1) with ideal torque sources, stepped one control period at a time.

    Parameters
    ----------
    config : TwinConfig or None
        ``params`` (the true plant), ``physics_rate`` (the RK4 step), ``control_rate`` and
        ``fall_angle`` are used; ``motor`` is not (ideal torque sources); ``ground`` and
        ``disturbances`` must be the defaults. None: ``TwinConfig(motor=None)``.
    theta0, alpha0 : float
        Initial pitch and heading, rad.
    position : (float, float)
        Initial axle midpoint (x, y), m.
    disturbance : callable or None
        ``disturbance(t) -> (τ1, τ2, τ3)`` in N·m, equation (1)'s lumped torques, evaluated
        at the start of every physics step (t in s).
    initial : (8,) or None
        A state [θ, θ̇, ψ, ψ̇, α, α̇, X, Y] every run starts from instead of
        [θ0, 0, 0, 0, α0, 0, x, y].
    """

    trusted = True  # its truth is finite and well formed by construction: the loop need not check it
    applies_motor = False  # ideal torque sources: config.motor is not used

    def __init__(self, config: TwinConfig | None = None, theta0: float = 0.0, alpha0: float = 0.0,
                 position=(0.0, 0.0), disturbance=None, initial=None):
        config = TwinConfig(motor=None) if config is None else config
        if not isinstance(config, TwinConfig):
            raise TwinError(f"config must be a TwinConfig, got {type(config).__name__}")
        if config.ground != Ground():
            raise TwinError(f"the analytic plant rolls on a level floor without slip: ground must be Ground() (the "
                            f"default), got {config.ground!r}; use the PyBullet twin for slopes and friction")
        if config.disturbances != Disturbances():
            raise TwinError("the analytic plant has no pushes, payload, centre-of-mass offset or friction changes "
                            "(config.disturbances must be the default); use the PyBullet twin, or the "
                            "disturbance(t) torques τ1..τ3 of equation (1)")
        if disturbance is not None and not callable(disturbance):
            raise TwinError(f"disturbance must be a function of t returning (τ1, τ2, τ3) in N·m, got {disturbance!r}")
        if initial is not None:
            x = np.asarray(initial, dtype=float)
            if x.shape != (8,) or not np.all(np.isfinite(x)):
                raise TwinError(f"initial must be 8 finite numbers {STATE_NAMES}, got shape {x.shape}")
            initial = x.copy()
        self.config = config
        self.params = p = config.params
        self.control_rate = config.control_rate
        self.k = config.steps_per_control
        self.physics_dt = 1.0 / config.physics_rate
        self.control_dt = 1.0 / config.control_rate
        self.gravity = p.g
        self.com_local = (0.0, 0.0, p.l)
        self.disturbance = disturbance
        self.initial = initial
        self._b_r = p.b / p.r
        self.actuation = Actuation(0.0, 0.0, 0.0, 0.0, False, False)
        self.push_force = _ZERO3
        self.reset(theta0, alpha0, position)

    def reset(self, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0)) -> GroundTruth:
        """A new run at rest (or at ``initial``); returns the truth at t = 0."""
        theta0, alpha0, (x0, y0) = checked_start(theta0, alpha0, position, self.config.fall_angle)
        if self.initial is not None:
            self.x = self.initial.copy()
        else:
            self.x = np.array([theta0, 0.0, 0.0, 0.0, alpha0, 0.0, x0, y0])
        self._alpha0 = alpha0 if self.initial is None else 0.0
        self.n = 0  # control periods since the start
        self.status, self.end_reason = "running", ""
        self.actuation = Actuation(0.0, 0.0, 0.0, 0.0, False, False)
        self.truth = self._truth()
        self._check_end()
        return self.truth

    def step(self, ul: float, ur: float) -> GroundTruth:
        """Hold ``ul``, ``ur`` (N·m) for one control period of RK4 steps; the truth at its end."""
        if self.status != "running":
            raise TwinError(f"the run has ended ({self.status}: {self.end_reason}); call reset()")
        try:
            finite = math.isfinite(ul) and math.isfinite(ur)
        except TypeError:
            finite = False
        if not finite:
            raise TwinError(f"wheel torque commands must be finite numbers in N·m, got ul={ul!r}, ur={ur!r}")
        x, p, dt, k, dist = self.x, self.params, self.physics_dt, self.k, self.disturbance
        first = self.n * k
        for j in range(k):
            x = rk4_step(x, ul, ur, p, dt, None if dist is None else dist((first + j) * dt))
        self.x = x
        self.n += 1
        self.actuation = Actuation(0.0, 0.0, float(ul), float(ur), False, False)
        self.truth = self._truth()
        self._check_end()
        return self.truth

    def close(self) -> None:
        """Nothing to free; a running plant ends as "closed" (as the twin does)."""
        if self.status == "running":
            self.status, self.end_reason = "closed", "the plant was closed"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def t(self) -> float:
        return self.n * self.control_dt

    @property
    def kinematics(self):
        """The body's pose and velocity now (:func:`planar_kinematics`), for the IMU."""
        th, th_d, _, psi_d, al, al_d, X, Y = (float(v) for v in self.x)
        p = self.params
        return planar_kinematics(th, th_d, al, al_d, p.r * psi_d, (X, Y, p.r), self.com_local)

    def _truth(self) -> GroundTruth:
        th, th_d, psi, psi_d, al, al_d, X, Y = (float(v) for v in self.x)
        half = self._b_r * (al - self._alpha0)
        turn = self._b_r * al_d
        return GroundTruth(self.n * self.control_dt, th, th_d, psi - half, psi + half, psi, psi_d, al, al_d,
                           self.params.r * psi, X, Y, 0.0, psi_d - turn, psi_d + turn)

    def _check_end(self) -> None:
        tr = self.truth
        if not all(map(math.isfinite, self.x)):
            self.status, self.end_reason = "diverged", f"the analytic model's state is not finite at t = {tr.t:.3f} s"
        elif abs(tr.theta) > self.config.fall_angle:
            self.status = "fell"
            self.end_reason = (f"the body tilted {abs(tr.theta):.3f} rad from the vertical, past the fall limit "
                               f"{self.config.fall_angle:g} rad, at t = {tr.t:.3f} s")


__all__ = ["AnalyticPlant", "planar_kinematics"]
