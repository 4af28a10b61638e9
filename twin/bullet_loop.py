"""Closed loop on the PyBullet twin: controllers → motors → physics → ground truth.

The controllers act on ground truth here (ideal sensing); the sensor models and the
estimator put themselves between the twin and the controllers in the next layer.

Logged at the control rate: row i holds the ground truth at t_i, the command computed
from it, and what the motors delivered and the pushes did over [t_i, t_i+1) (period
means). A run that falls stops at the row where that was detected; its last row's
actuation is zero, because nothing was applied after it. A run that diverges (a
non-finite state from the physics) stops at the last finite row: no NaN is logged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from twin.analytic_loop import Experiment
from twin.controllers.cascade import FuzzyCascade
from twin.errors import TwinError
from twin.metrics import settling_time
from twin.plant.bullet import ACTUATION_UNITS, TRUTH_UNITS, Actuation, BulletTwin, GroundTruth, TwinConfig

TRUTH_NAMES = GroundTruth._fields
COMMAND_NAMES = ("ul_cmd", "ur_cmd", "u", "theta_off", "u_alpha")
COMMAND_UNITS = dict(ul_cmd="N·m", ur_cmd="N·m", u="N·m", theta_off="rad", u_alpha="N·m")
ACTUATION_NAMES = Actuation._fields
PUSH_NAMES = ("push_fx", "push_fy", "push_fz")
PUSH_UNITS = dict(push_fx="N", push_fy="N", push_fz="N")


@dataclass
class TwinRun:
    """A closed-loop trajectory on the twin (see the module docstring for the row layout).

    ``truth`` (n, 15) columns :data:`TRUTH_NAMES`; ``commands`` (n, 5)
    :data:`COMMAND_NAMES`; ``actuation`` (n, 6) :data:`ACTUATION_NAMES`; ``push`` (n, 3)
    N, world frame. ``status`` is "ok" (ran its duration), "fell" or "diverged".
    """

    t: np.ndarray
    truth: np.ndarray
    commands: np.ndarray
    actuation: np.ndarray
    push: np.ndarray
    status: str
    end_reason: str
    config: TwinConfig = field(repr=False)
    experiment: Experiment | None = None
    controller: str = ""

    @property
    def fell(self) -> bool:
        return self.status != "ok"

    def signal(self, name: str) -> np.ndarray:
        """One logged signal by name (truth, command, actuation or push column)."""
        for names, data in ((TRUTH_NAMES, self.truth), (COMMAND_NAMES, self.commands),
                            (ACTUATION_NAMES, self.actuation), (PUSH_NAMES, self.push)):
            if name in names:
                return data[:, names.index(name)]
        raise TwinError(f"no signal {name!r}; signals: {', '.join(self.signal_names())}")

    @staticmethod
    def signal_names() -> tuple[str, ...]:
        return TRUTH_NAMES + COMMAND_NAMES + ACTUATION_NAMES + PUSH_NAMES

    @staticmethod
    def signal_units() -> dict[str, str]:
        return {**TRUTH_UNITS, **COMMAND_UNITS, **ACTUATION_UNITS, **PUSH_UNITS}

    @property
    def distance(self) -> np.ndarray:
        """Travelled distance p = r ψ in m."""
        return self.signal("distance")

    @property
    def total_torque(self) -> np.ndarray:
        """Torque delivered by both motors, N·m."""
        return self.signal("torque_l") + self.signal("torque_r")

    def columns(self) -> tuple[list[str], list[str], np.ndarray]:
        """(names, units, data (n, k)) of everything logged, for CSV files."""
        names = list(self.signal_names())
        units = [self.signal_units()[n] for n in names]
        return names, units, np.column_stack([self.truth, self.commands, self.actuation, self.push])

    def settling_time(self, tol: float = 0.01) -> float:
        """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does or fell."""
        if self.fell:
            return math.inf
        return settling_time(self.t, self.signal("theta"), tol)

    def summary(self) -> dict:
        e = self.experiment
        out = {
            "controller": self.controller,
            "status": self.status,
            "end_reason": self.end_reason,
            "duration_s": float(self.t[-1]),
            "settling_time_s": self.settling_time(),
            "final_theta_rad": float(self.signal("theta")[-1]),
            "max_abs_torque_nm": float(np.max(np.abs(self.actuation[:, 2:4]))),
            "saturated_fraction": float(np.mean(self.actuation[:-1, 4:6] > 0)) if len(self.t) > 1 else 0.0,
            "final_distance_m": float(self.signal("distance")[-1]),
            "final_heading_rad": float(self.signal("alpha")[-1]),
        }
        if e is not None and e.p_d is not None:
            out["final_position_error_m"] = out["final_distance_m"] - e.p_d
        if e is not None and e.alpha_d is not None:
            out["final_heading_error_rad"] = out["final_heading_rad"] - e.alpha_d
        return out


def simulate_twin(controller: FuzzyCascade, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0)) -> TwinRun:
    """Run ``controller`` on a new twin built from ``config`` from the experiment's θ0.

    The twin is closed when the run ends, fallen or not.
    """
    config = config if config is not None else TwinConfig()
    duration = experiment.duration if duration is None else float(duration)
    control_dt = 1.0 / config.control_rate
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    n_ctrl = int(round(duration / control_dt))
    truth = np.zeros((n_ctrl + 1, len(TRUTH_NAMES)))
    cmds = np.zeros((n_ctrl + 1, len(COMMAND_NAMES)))
    act = np.zeros((n_ctrl + 1, len(ACTUATION_NAMES)))
    push = np.zeros((n_ctrl + 1, 3))
    p_d, alpha_d = experiment.p_d, experiment.alpha_d
    with BulletTwin(config, theta0=experiment.theta0, alpha0=alpha0, position=position) as twin:
        tr = twin.truth
        n = n_ctrl + 1
        for i in range(n_ctrl + 1):
            if twin.status == "diverged":
                n = i  # the non-finite state is not logged: the log ends with the last finite one
                break
            truth[i] = tr
            c = controller(tr.state6(), p_d, alpha_d)
            cmds[i] = (c.ul, c.ur, c.u, c.theta_off, c.u_alpha)
            if i == n_ctrl or twin.status != "running":
                n = i + 1
                break
            tr = twin.step(c.ul, c.ur)
            act[i] = twin.actuation
            push[i] = twin.push_force
        status = "ok" if twin.status == "running" else twin.status
        reason = "" if status == "ok" else twin.end_reason
    t = truth[:n, 0].copy()
    return TwinRun(t, truth[:n], cmds[:n], act[:n], push[:n], status, reason, config, experiment, controller_name)
