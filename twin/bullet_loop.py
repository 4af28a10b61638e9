"""A whole run on the PyBullet twin, logged: :func:`simulate_twin` drives :class:`twin.loop.ClosedLoop`.

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the ``ideal`` estimator passes the ground truth through), kept
as a reference.

Logged at the control rate: row i holds the ground truth at t_i, what the controllers
were given at t_i (``estimates``), the command computed from it, and what the motors
delivered and the pushes did over [t_i, t_i+1) (period means). A run that falls stops at
the row where that was detected; its last row's actuation is zero, because nothing was
applied after it. A run that diverges (a non-finite state from the physics) stops at the
last finite row: no NaN is logged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.metrics import settling_time
from twin.params import NOMINAL, RobotParams
from twin.plant.bullet import ACTUATION_UNITS, TRUTH_UNITS, Actuation, GroundTruth, TwinConfig
from twin.sensors import Measurement, SensorConfig

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
class TwinRun:
    """A closed-loop trajectory on the twin (see the module docstring for the row layout).

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
    config: TwinConfig = field(repr=False)
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


def simulate_twin(controller, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator="ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None, estimator_params: dict | None = None) -> TwinRun:
    """Run ``controller`` on a new twin built from ``config`` from the experiment's θ0.

    A driver of :class:`twin.loop.ClosedLoop`: reset, then the controller's command and a
    step per control period, everything logged (see the module docstring).

    Parameters
    ----------
    controller : Controller
        Meets :class:`twin.protocols.Controller` (a built-in from :mod:`twin.registry`
        or one's own).
    sensors : SensorConfig or None
        The IMU, encoders and faults; None: ideal sensing (the ``ideal`` estimator, the
        controllers read the truth).
    estimator : str or Estimator
        A kind from :mod:`twin.registry` (built-in name or ``"package.module:attribute"``,
        built with ``estimator_params``), or an object meeting :class:`twin.protocols.Estimator`.
    seed : int
        The run's seed: the sensors' noise and faults are drawn from it (and nothing else).
    model_params : RobotParams
        The robot the estimator assumes (the controllers' nominal model by default).
    log_filter : bool
        Keep the estimator's ``diagnostics()`` at every step (for the EKF: its own state,
        covariance and NIS, ``filter_log``).
    progress : callable or None
        ``progress(steps_done, steps_total)``, called once per simulated second and at the end.

    The twin is closed when the run ends, fallen or not.
    """
    from twin.loop import ClosedLoop
    from twin.registry import BuildContext, build_estimator

    config = config if config is not None else TwinConfig()
    duration = experiment.duration if duration is None else float(duration)
    control_dt = 1.0 / config.control_rate
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    if sensors is not None and not isinstance(sensors, SensorConfig):
        raise TwinError(f"sensors must be a SensorConfig or None (ideal sensing), got {sensors!r}")
    if sensors is not None:
        sensors.steps(config.control_rate)  # rates and latencies fit the control period: check before building
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TwinError(f"seed must be a non-negative integer, got {seed!r}")
    ideal = sensors is None
    if isinstance(estimator, str) or ideal:
        kind = "ideal" if ideal else estimator
        context = BuildContext(config.control_rate, model_params, config.motor, sensors, experiment.targets, alpha0)
        filt = build_estimator(kind, estimator_params, context)
        sensing = kind
    else:
        filt, sensing = estimator, getattr(estimator, "name", type(estimator).__name__)
    loop = ClosedLoop(config, filt, controller, sensors, experiment.targets, experiment.theta0, alpha0, position)
    n_ctrl = int(round(duration / control_dt))
    report_every = max(1, int(round(config.control_rate)))
    n_rows = n_ctrl + 1
    # rows collected as tuples (cheaper per step than writing numpy rows), stacked at the end
    truth, est, cmds, act, push = [], [], [], [], []
    meas_log: list[Measurement] = []
    bias_log = None if ideal else np.full((n_rows, 3), np.nan)
    diag = [] if log_filter else None
    n = n_rows
    with loop:
        loop.reset(seed)
        for i in range(n_rows):
            if loop.status == "diverged":
                n = i  # the non-finite state is not logged: the log ends with the last finite one
                break
            truth.append(loop.truth)
            if not ideal:
                meas_log.append(loop.measurement)
                if loop.true_gyro_bias is not None:
                    bias_log[i] = loop.true_gyro_bias
            if diag is not None:
                diag.append(loop.diagnostics())
            est.append(loop.estimate)
            c = loop.command()
            cmds.append(c)
            if i == n_ctrl or loop.status != "running":
                n = i + 1
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            loop.step(c)
            act.append(loop.actuation)
            push.append(loop.push_force)
        status = "ok" if loop.status == "running" else loop.status
        reason = "" if status == "ok" else loop.end_reason
        stats = {} if ideal else loop.estimator_stats()
        sensor_counts = {} if ideal else loop.suite.fault_counts()
        sensor_truth = {} if ideal else loop.suite.truth()
        if progress is not None:
            progress(n_ctrl, n_ctrl)
    names = ("ul_cmd", "ur_cmd") + loop.signals
    truth = np.array(truth[:n], dtype=float).reshape(n, len(TRUTH_NAMES))
    est = np.array(est[:n], dtype=float).reshape(n, len(ESTIMATE_NAMES))
    cmds = np.array(cmds[:n], dtype=float).reshape(n, len(names))
    # the last row's actuation is zero: nothing was applied after it
    act = np.array(act[:n] + [(0.0,) * len(ACTUATION_NAMES)] * (n - len(act[:n])), dtype=float).reshape(
        n, len(ACTUATION_NAMES))
    push = np.array(push[:n] + [(0.0,) * 3] * (n - len(push[:n])), dtype=float).reshape(n, 3)
    t = truth[:, 0].copy()
    units = {**COMMAND_UNITS, **getattr(controller, "signal_units", {})}
    return TwinRun(t, truth, cmds, act, push, status, reason, config, experiment, controller_name,
                   estimates=est, sensing=sensing, measurements=meas_log[:n],
                   estimator_stats=stats, sensor_counts=sensor_counts,
                   gyro_bias=None if ideal else bias_log[:n], filter_log=_filter_log(diag, n),
                   seed=None if ideal else int(seed), sensor_truth=sensor_truth, sensor_config=sensors,
                   model_params=model_params, command_names=names,
                   command_units=tuple(units.get(k, "1") for k in names))


def _filter_log(diag: list | None, n: int) -> dict | None:
    """The estimator's per-step diagnostics as arrays: for the EKF ``x`` (n, 12), ``P`` (n, 12, 12),
    ``nis`` (n,), ``nis_dof`` (n,) and ``lag`` (control periods); None if not logged or no hook."""
    if not diag or diag[0] is None:
        return None
    diag = diag[:n]
    out = {}
    for key, first in diag[0].items():
        if key == "lag":
            out[key] = first
        elif key == "nis_dof":
            out[key] = np.array([d[key] for d in diag], dtype=int)
        else:
            out[key] = np.array([d[key] for d in diag], dtype=float)
    return out
