"""Closed loop on the analytic model: the paper's three experiments, the reference
against which the PyBullet twin is checked.

The plant (equation 1, :mod:`twin.plant.analytic`) is integrated with fixed-step RK4 at
``physics_dt``; the controllers run every ``control_dt`` (a whole number of physics
steps) with a zero-order hold, as on the real robot's microcontroller. The controllers
see the true state here (the estimator comes with the sensor models).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from twin.controllers.cascade import build_cascade
from twin.controllers.lmi import BalanceDesign, design_balance_gains
from twin.errors import TwinError
from twin.experiments import PAPER_EXPERIMENTS, Experiment
from twin.metrics import settling_time
from twin.params import NOMINAL, RobotParams
from twin.plant.analytic import STATE_NAMES, STATE_UNITS, rk4_step
from twin.timing import steps_per_control


@dataclass
class AnalyticRun:
    """A trajectory: ``t`` (n,) s; ``x`` (n, 8) state (see ``STATE_NAMES``); commands (n,)."""

    t: np.ndarray
    x: np.ndarray
    ul: np.ndarray
    ur: np.ndarray
    u: np.ndarray
    theta_off: np.ndarray
    u_alpha: np.ndarray
    params: RobotParams = field(repr=False)
    experiment: Experiment | None = None
    controller: str = ""

    def signal(self, name: str) -> np.ndarray:
        return self.x[:, STATE_NAMES.index(name)]

    @property
    def distance(self) -> np.ndarray:
        """Travelled distance p = r ψ in m."""
        return self.params.r * self.signal("psi")

    @property
    def total_torque(self) -> np.ndarray:
        """ul + ur in N·m, as applied."""
        return self.ul + self.ur

    def columns(self) -> tuple[list[str], list[str], np.ndarray]:
        """(names, units, data (n, k)) of everything logged, for CSV files."""
        names = ["t", *STATE_NAMES, "ul", "ur", "u_balance", "theta_off", "u_alpha"]
        units = ["s", *STATE_UNITS, "N·m", "N·m", "N·m", "rad", "N·m"]
        data = np.column_stack([self.t, self.x, self.ul, self.ur, self.u, self.theta_off, self.u_alpha])
        return names, units, data

    def settling_time(self, tol: float = 0.01) -> float:
        """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does."""
        return settling_time(self.t, self.signal("theta"), tol)

    def summary(self) -> dict:
        e = self.experiment
        out = {
            "controller": self.controller,
            "settling_time_s": self.settling_time(),
            "final_theta_rad": float(self.x[-1, 0]),
            "max_abs_u_nm": float(np.max(np.abs(self.u))),
            "max_abs_wheel_torque_nm": float(max(np.max(np.abs(self.ul)), np.max(np.abs(self.ur)))),
            "final_distance_m": float(self.distance[-1]),
            "final_heading_rad": float(self.signal("alpha")[-1]),
        }
        if e is not None and e.p_d is not None:
            out["final_position_error_m"] = float(self.distance[-1] - e.p_d)
        if e is not None and e.alpha_d is not None:
            out["final_heading_error_rad"] = float(self.signal("alpha")[-1] - e.alpha_d)
        return out


def simulate(controller, experiment: Experiment, params: RobotParams = NOMINAL,
             duration: float | None = None, physics_dt: float = 0.001, control_dt: float = 0.005,
             x0=None, disturbance=None, controller_name: str = "") -> AnalyticRun:
    """Run ``controller`` on the analytic plant ``params`` (the "true plant").

    ``disturbance(t) -> (τ1, τ2, τ3)`` in N·m, optional. ``x0`` (8,) overrides the
    experiment's initial state [θ0, 0, …]. Logged at the control rate.
    """
    k = steps_per_control(physics_dt, control_dt)
    duration = experiment.duration if duration is None else float(duration)
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    n_ctrl = int(round(duration / control_dt))  # logged at the control rate: duration rounds to it
    x = np.zeros(8)
    x[0] = experiment.theta0
    if x0 is not None:
        x = np.asarray(x0, dtype=float)
        if x.shape != (8,) or not np.all(np.isfinite(x)):
            raise TwinError(f"x0 must be 8 finite numbers {STATE_NAMES}, got shape {x.shape}")
        x = x.copy()
    targets = experiment.targets
    if hasattr(controller, "reset"):
        controller.reset(targets)
    log = np.empty((n_ctrl + 1, 8))
    cmds = np.zeros((n_ctrl + 1, 5))
    for i in range(n_ctrl + 1):
        log[i] = x
        if not np.all(np.isfinite(x)):
            raise TwinError(f"the analytic simulation diverged at t = {i * control_dt:.3f} s")
        c = tuple(controller(x, targets))  # (ul, ur, *signals); the cascade's signals are u, θ_off, u_α
        cmds[i, :min(5, len(c))] = c[:5]
        if i == n_ctrl:
            break
        for j in range(k):
            tau = None if disturbance is None else disturbance((i * k + j) * physics_dt)
            x = rk4_step(x, c[0], c[1], params, physics_dt, tau)
    t = np.arange(n_ctrl + 1) * control_dt
    return AnalyticRun(t, log, cmds[:, 0], cmds[:, 1], cmds[:, 2], cmds[:, 3], cmds[:, 4], params, experiment,
                       controller_name)


def run_paper_experiment(number: int, kind: str = "it2", design: BalanceDesign | None = None,
                         plant: RobotParams = NOMINAL, model: RobotParams = NOMINAL, **kwargs) -> AnalyticRun:
    """Paper experiment 1, 2 or 3 with the ``kind`` controllers designed on ``model``."""
    if number not in PAPER_EXPERIMENTS:
        raise TwinError(f"paper experiment must be 1, 2 or 3, got {number!r}")
    exp = PAPER_EXPERIMENTS[number]
    design = design or design_balance_gains(model)
    ctrl = build_cascade(kind, design, exp.targets, model)
    return simulate(ctrl, exp, plant, controller_name=kind, **kwargs)
