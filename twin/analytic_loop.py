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

from twin.controllers.balance import PDCBalanceController
from twin.controllers.cascade import DEFAULT_PSI_ERROR_LIMIT, FuzzyCascade
from twin.controllers.lmi import BalanceDesign, design_balance_gains
from twin.controllers.mamdani import DEFAULT_FOU, direction_controller, position_controller
from twin.errors import TwinError
from twin.metrics import settling_time
from twin.params import NOMINAL, RobotParams
from twin.plant.analytic import STATE_NAMES, STATE_UNITS, rk4_step
from twin.timing import steps_per_control


@dataclass(frozen=True)
class Experiment:
    """Initial state and targets of a run. ``p_d`` in m, ``alpha_d`` in rad (None: loop off)."""

    name: str
    description: str
    theta0: float = 0.48  # rad
    p_d: float | None = None
    alpha_d: float | None = None
    duration: float = 15.0  # s


PAPER_EXPERIMENTS = {
    1: Experiment("paper-exp1", "balance only from θ0 = 0.48 rad"),
    2: Experiment("paper-exp2", "balance + position, p_d = 0.7 m", p_d=0.7),
    3: Experiment("paper-exp3", "balance + position + direction, p_d = 1 m, α_d = 1.5 rad", p_d=1.0, alpha_d=1.5),
}


def build_cascade(kind: str, design: BalanceDesign, experiment: Experiment, params: RobotParams = NOMINAL,
                  fou: float = DEFAULT_FOU, type_reduction: str = "bmm",
                  psi_error_limit: float = DEFAULT_PSI_ERROR_LIMIT) -> FuzzyCascade:
    """The IT2 (``kind="it2"``) or type-1 (``"t1"``) controllers an experiment needs."""
    balance = PDCBalanceController(design.gains, kind)
    position = position_controller(kind, fou, type_reduction) if experiment.p_d is not None else None
    direction = direction_controller(kind, fou, type_reduction) if experiment.alpha_d is not None else None
    return FuzzyCascade(balance, position, direction, params.r, psi_error_limit)


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


def simulate(controller: FuzzyCascade, experiment: Experiment, params: RobotParams = NOMINAL,
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
    log = np.empty((n_ctrl + 1, 8))
    cmds = np.zeros((n_ctrl + 1, 5))
    for i in range(n_ctrl + 1):
        log[i] = x
        if not np.all(np.isfinite(x)):
            raise TwinError(f"the analytic simulation diverged at t = {i * control_dt:.3f} s")
        c = controller(x, experiment.p_d, experiment.alpha_d)
        cmds[i] = (c.ul, c.ur, c.u, c.theta_off, c.u_alpha)
        if i == n_ctrl:
            break
        for j in range(k):
            tau = None if disturbance is None else disturbance((i * k + j) * physics_dt)
            x = rk4_step(x, c.ul, c.ur, params, physics_dt, tau)
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
    ctrl = build_cascade(kind, design, exp, model)
    return simulate(ctrl, exp, plant, controller_name=kind, **kwargs)
