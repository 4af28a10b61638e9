"""The one run-result type: a closed-loop trajectory, from the twin or the analytic model.

Row i holds the ground truth at t_i, what the controllers were given at t_i
(``estimates``), the command computed from it, and what the motors delivered and the
pushes did over [t_i, t_i+1) (period means). A run that falls stops at the row where that
was detected; its last row's actuation is zero, because nothing was applied after it. A
run that diverges (a non-finite state from the physics) stops at the last finite row: no
NaN is logged. :func:`twin.metrics.run_metrics` gives every run's figures of merit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.metrics import settling_time
from twin.params import RobotParams
from twin.plant.bullet import ACTUATION_UNITS, TRUTH_UNITS, Actuation, GroundTruth, TwinConfig
from twin.sensors import SensorConfig

TRUTH_NAMES = GroundTruth._fields
ESTIMATE_NAMES = ("theta_est", "theta_dot_est", "psi_est", "psi_dot_est", "alpha_est", "alpha_dot_est")
ESTIMATE_UNITS = dict(theta_est="rad", theta_dot_est="rad/s", psi_est="rad", psi_dot_est="rad/s", alpha_est="rad",
                      alpha_dot_est="rad/s")
COMMAND_NAMES = ("ul_cmd", "ur_cmd", "u", "theta_off", "u_alpha")  # the fuzzy cascade's (and LQR's)
COMMAND_UNITS = dict(ul_cmd="N·m", ur_cmd="N·m", u="N·m", theta_off="rad", u_alpha="N·m")
ACTUATION_NAMES = Actuation._fields
PUSH_NAMES = ("push_fx", "push_fy", "push_fz")
PUSH_UNITS = dict(push_fx="N", push_fy="N", push_fz="N")


@dataclass
class Run:
    """A closed-loop trajectory (see the module docstring for the row layout).

    ``plant`` is "twin" (:func:`twin.bullet_loop.simulate_twin`) or "analytic"
    (:func:`twin.analytic_loop.simulate`: equation (1), ideal torque sources, the
    controllers reading the truth; its ``config`` is None).

    ``truth`` (n, 15) columns :data:`TRUTH_NAMES`; ``estimates`` (n, 6)
    :data:`ESTIMATE_NAMES`, the state the controllers were given; ``commands`` (n, k)
    ``command_names``: ul_cmd, ur_cmd (N·m) and the controller's extra signals
    (:data:`COMMAND_NAMES` for the fuzzy cascade and LQR); ``actuation`` (n, 6) :data:`ACTUATION_NAMES`; ``push`` (n, 3)
    N, world frame. ``status`` is "ok" (ran its duration), "fell" or "diverged".
    ``sensing`` is "ideal" or the estimator's name; ``measurements`` what reached the
    estimator at each step; ``estimator_stats`` its counts (rejected measurements,
    resets, events); ``gyro_bias`` (n, 3) rad/s the gyro's true bias in the sample taken
    at each step (NaN without one); ``sensor_truth`` the sensors' drawn constants (scale
    factors, turn-on biases, encoder phases); ``sensor_config`` and ``model_params`` what the
    run was given; ``filter_log`` (EKF with ``log_filter``) the
    filter's own state ``x`` (n, 12) and covariance ``P`` (n, 12, 12) at t_{i − lag} (see
    :mod:`estimation.ekf`), and the encoder update's ``nis`` (n,) (NaN where none was tried) with its degrees of freedom
    ``nis_dof`` (n,) (the number of wheels whose count changed; 0 where none was tried).
    """

    t: np.ndarray
    truth: np.ndarray
    commands: np.ndarray
    actuation: np.ndarray
    push: np.ndarray
    status: str
    end_reason: str
    config: TwinConfig | None = field(repr=False)
    experiment: Experiment | None = None
    controller: str = ""
    estimates: np.ndarray | None = None
    sensing: str = "ideal"
    measurements: list = field(default_factory=list, repr=False)
    estimator_stats: dict = field(default_factory=dict)
    sensor_counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = field(default=None, repr=False)
    filter_log: dict | None = field(default=None, repr=False)
    seed: int | None = None
    sensor_truth: dict = field(default_factory=dict, repr=False)
    sensor_config: SensorConfig | None = field(default=None, repr=False)
    model_params: RobotParams | None = field(default=None, repr=False)
    command_names: tuple = COMMAND_NAMES
    command_units: tuple = tuple(COMMAND_UNITS[k] for k in COMMAND_NAMES)
    plant: str = "twin"

    @property
    def fell(self) -> bool:
        return self.status != "ok"

    def signal(self, name: str) -> np.ndarray:
        """One logged signal by name (truth, estimate, command, actuation or push column)."""
        for names, data in ((TRUTH_NAMES, self.truth), (ESTIMATE_NAMES, self.estimates),
                            (self.command_names, self.commands), (ACTUATION_NAMES, self.actuation),
                            (PUSH_NAMES, self.push)):
            if name in names:
                return data[:, names.index(name)]
        raise TwinError(f"no signal {name!r}; signals: {', '.join(self.signal_names())}")

    def signal_names(self) -> tuple[str, ...]:
        return TRUTH_NAMES + ESTIMATE_NAMES + tuple(self.command_names) + ACTUATION_NAMES + PUSH_NAMES

    def signal_units(self) -> dict[str, str]:
        return {**TRUTH_UNITS, **ESTIMATE_UNITS, **dict(zip(self.command_names, self.command_units)),
                **ACTUATION_UNITS, **PUSH_UNITS}

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
        return names, units, np.column_stack([self.truth, self.estimates, self.commands, self.actuation, self.push])

    def settling_time(self, tol: float = 0.01) -> float:
        """First time (s) after which |θ| stays below ``tol`` rad; inf if it never does or fell."""
        if self.fell:
            return math.inf
        return settling_time(self.t, self.signal("theta"), tol)

    def estimation_rmse(self, name: str = "theta", start: float = 0.0) -> float:
        """RMS of (estimate − truth) of ``name`` (θ, θ̇, ψ, ψ̇, α or α̇) from ``start`` s on."""
        keep = self.t >= start - 1e-9
        err = self.signal(name + "_est")[keep] - self.signal(name)[keep]
        from twin.metrics import exact_mean

        return math.sqrt(exact_mean(err * err)) if err.size else math.nan


TwinRun = Run  # the name it had when only the twin made runs

