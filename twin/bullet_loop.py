"""A whole run, logged as a :class:`twin.runs.Run`: :func:`simulate_twin` drives
:class:`twin.loop.ClosedLoop` on the PyBullet twin (by default) or on any
:class:`twin.protocols.Plant` (``plant``: "analytic" for equation (1), or one's own object).

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the ``ideal`` estimator passes the ground truth through), kept
as a reference.

Logged at the control rate, one row per control instant (see :mod:`twin.runs`), or at
every N-th instant (``log_every``). Memory: the rows are gathered as tuples (the cheapest
thing to append in the loop) for a chunk of :data:`CHUNK` control steps at a time, then
moved into preallocated float64 arrays, so a run costs about 8 bytes per logged number
(some 0.27 GB per simulated hour at 200 Hz with sensors, every step logged).
"""
from __future__ import annotations

import math

import numpy as np

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.params import NOMINAL, RobotParams
from twin.plant.bullet import TwinConfig
from twin.runs import (ACTUATION_NAMES, COMMAND_NAMES, COMMAND_UNITS, ESTIMATE_NAMES, ESTIMATE_UNITS,
                       FULL_RATE_NAMES, PUSH_NAMES, PUSH_UNITS, TRUTH_NAMES, MeasurementLog, Run, TwinRun)
from twin.sensors import SensorConfig

CHUNK = 4096  # control steps gathered as tuples before they move into the log's arrays

__all__ = ["ACTUATION_NAMES", "COMMAND_NAMES", "COMMAND_UNITS", "ESTIMATE_NAMES", "ESTIMATE_UNITS", "PUSH_NAMES",
           "PUSH_UNITS", "Run", "TRUTH_NAMES", "TwinRun", "simulate_twin"]


def simulate_twin(controller, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator="ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None, estimator_params: dict | None = None, log_every: int = 1, plant=None) -> Run:
    """Run ``controller`` on a new twin built from ``config`` (or on ``plant``) from the experiment's θ0.

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
    plant : None, str or Plant
        None or "bullet": the PyBullet twin on ``config``, new for the run; "analytic": equation
        (1) on ``config`` (:class:`twin.plant.analytic_plant.AnalyticPlant`: RK4 at the
        physics rate, ideal torque sources); or an object meeting :class:`twin.protocols.Plant`
        (its control rate is the run's; ``config`` then only fills in what it does not say).
    log_every : int
        Log every N-th control step (N ≥ 1): row i of the run is step i·N (t = i·N·T); the
        other steps are not kept. The signals the metrics read are kept at every step
        (``Run.full_rate``), so :func:`twin.metrics.run_metrics` gives the same figures for
        every N. N > 1 excludes ``log_filter`` (the EKF's consistency checks need every step).

    The twin (the plant) is closed when the run ends, fallen or not.
    """
    from twin.loop import ClosedLoop
    from twin.registry import BuildContext, build_estimator

    config = config if config is not None else TwinConfig()
    plant_name, motor = "twin", config.motor
    if isinstance(plant, str):
        from twin.plant import build_plant

        plant = None if plant == "bullet" else build_plant(plant, config, experiment.theta0, alpha0, position)
    if plant is not None:
        from twin.plant import check_plant
        from twin.plant.analytic_plant import AnalyticPlant
        from twin.plant.bullet import BulletTwin
        from twin.protocols import describe_object

        check_plant(plant, sensors is not None)
        own = getattr(plant, "config", None)
        if isinstance(own, TwinConfig):
            config = own
        if isinstance(plant, BulletTwin):
            motor = plant.config.motor
        else:  # the analytic plant's torque sources are ideal; one's own plant says nothing of motors
            motor = None
            plant_name = "analytic" if isinstance(plant, AnalyticPlant) else describe_object(plant)
    rate = config.control_rate if plant is None else float(plant.control_rate)
    duration = experiment.duration if duration is None else float(duration)
    control_dt = 1.0 / rate
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    if sensors is not None and not isinstance(sensors, SensorConfig):
        raise TwinError(f"sensors must be a SensorConfig or None (ideal sensing), got {sensors!r}")
    if sensors is not None:
        sensors.steps(rate)  # rates and latencies fit the control period: check before building
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TwinError(f"seed must be a non-negative integer, got {seed!r}")
    every = check_log_every(log_every)
    if every > 1 and log_filter:
        raise TwinError(f"log_filter needs every control step (the filter's lagged states are matched to the truth "
                        f"step by step), so log_every must be 1 with it, got {log_every!r}")
    ideal = sensors is None
    if ideal and not (estimator in ("ekf", "ideal") if isinstance(estimator, str)
                      else getattr(estimator, "reads_truth", False)):
        raise TwinError(f"sensors=None is ideal sensing (the 'ideal' estimator reads the truth), so estimator "
                        f"{estimator!r} would not run; give sensors=SensorConfig(...) to use it")
    if isinstance(estimator, str) or ideal:
        kind = "ideal" if ideal else estimator
        context = BuildContext(rate, model_params, motor, sensors, experiment.targets, alpha0)
        filt = build_estimator(kind, estimator_params, context)
        sensing = kind
    else:
        filt, sensing = estimator, getattr(estimator, "name", type(estimator).__name__)
    loop = ClosedLoop(config if plant is None else plant, filt, controller, sensors, experiment.targets,
                      experiment.theta0, alpha0, position, limits=config.limits)
    n_ctrl = int(round(duration / control_dt))
    report_every = max(1, int(round(rate)))
    n_rows = n_ctrl + 1
    names = ("ul_cmd", "ur_cmd") + loop.signals
    log = _Log(n_rows, every, len(names), measured=not ideal, with_truth=bool(getattr(filt, "reads_truth", False)))
    truth, est, cmds, act, push = log.truth_rows, log.est_rows, log.cmd_rows, log.act_rows, log.push_rows
    meas_log, bias_log = log.meas_rows, log.bias_rows
    diag = [] if log_filter else None
    n = n_rows
    flush_at = CHUNK
    with loop:
        loop.reset(seed)
        twin = loop.twin  # read directly below: this loop runs once per control period
        # a plant without actuation or push_force: the loop's (the command delivered, no push)
        src = twin if hasattr(twin, "actuation") and hasattr(twin, "push_force") else loop
        command, step = loop.command, loop.step
        for i in range(n_rows):
            if twin.status == "diverged":
                n = i  # the non-finite state is not logged: the log ends with the last finite one
                break
            if i == flush_at:
                log.flush()
                flush_at += CHUNK
            truth.append(loop.truth)
            if not ideal:
                meas_log.append(loop.measurement)
                bias_log.append(loop.true_gyro_bias)
            if diag is not None:
                diag.append(loop.diagnostics())
            est.append(loop.estimate)
            c = command()
            cmds.append(c)
            if i == n_ctrl or twin.status != "running":
                n = i + 1
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            step(c)
            act.append(src.actuation)
            push.append(src.push_force)
        status = "ok" if loop.status == "running" else loop.status
        reason = "" if status == "ok" else loop.end_reason
        stats = {} if ideal else loop.estimator_stats()
        sensor_counts = {} if ideal else loop.suite.fault_counts()
        sensor_truth = {} if ideal else loop.suite.truth()
        if progress is not None:
            progress(n_ctrl, n_ctrl)
    # the last row's actuation is zero: nothing was applied after it
    act += [(0.0,) * len(ACTUATION_NAMES)] * (len(truth) - len(act))
    push += [(0.0,) * 3] * (len(truth) - len(push))
    log.flush()
    rows = log.kept(n)
    truth, est, cmds, act, push = (a[:rows] for a in (log.truth, log.est, log.cmds, log.act, log.push))
    t = truth[:, 0].copy()
    units = {**COMMAND_UNITS, **getattr(controller, "signal_units", {})}
    return Run(t, truth, cmds, act, push, status, reason, config, experiment, controller_name,
                   estimates=est, sensing=sensing, measurements=[] if ideal else log.meas[:rows],
                   estimator_stats=stats, sensor_counts=sensor_counts,
                   gyro_bias=None if ideal else log.bias[:rows], filter_log=_filter_log(diag, n),
                   seed=None if ideal else int(seed), sensor_truth=sensor_truth, sensor_config=sensors,
                   model_params=model_params, command_names=names,
                   command_units=tuple(units.get(k, "1") for k in names), log_every=every,
                   full_rate=None if log.full is None else {name: a[:n] for name, a in log.full.items()},
                   plant=plant_name)


def check_log_every(value) -> int:
    """``log_every`` as an int, or a TwinError naming what is allowed."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise TwinError(f"log_every must be a whole number of control steps ≥ 1 (1: log every step), got {value!r}")
    return int(value)


class _Log:
    """A run's log in preallocated float64 arrays, filled a chunk at a time.

    The loop appends each control step's tuples to the ``*_rows`` lists; :meth:`flush`
    moves every ``every``-th step of them (steps 0, N, 2N, …) into the arrays and empties
    the lists. With ``every`` > 1, :data:`FULL_RATE_NAMES` are also copied at every step
    into ``full`` (the metrics' signals). The arrays are allocated (``np.empty``) for the
    whole run, but only the rows written take memory: a run that falls early costs what it
    logged.
    """

    def __init__(self, n_rows: int, every: int, n_commands: int, measured: bool, with_truth: bool):
        self.every = every
        k = self.kept(n_rows)
        self.truth = np.empty((k, len(TRUTH_NAMES)))
        self.est = np.empty((k, len(ESTIMATE_NAMES)))
        self.cmds = np.empty((k, n_commands))
        self.act = np.empty((k, len(ACTUATION_NAMES)))
        self.push = np.empty((k, len(PUSH_NAMES)))
        self.meas = MeasurementLog.empty(k, with_truth) if measured else None
        self.bias = np.empty((k, 3)) if measured else None  # the gyro's true bias, NaN on steps without a sample
        self.full = {name: np.empty(n_rows) for name in FULL_RATE_NAMES} if every > 1 else None
        self.truth_rows, self.est_rows, self.cmd_rows, self.act_rows, self.push_rows = [], [], [], [], []
        self.meas_rows, self.bias_rows = [], []
        self.start = 0  # the control step of the lists' first row

    def kept(self, steps: int) -> int:
        """Rows logged out of the first ``steps`` control steps."""
        return (steps + self.every - 1) // self.every

    def flush(self) -> None:
        m = len(self.truth_rows)
        if not m:
            return
        s, every = self.start, self.every
        first = (-s) % every  # the lists' first row that is a logged step
        r0 = (s + first) // every
        r1 = r0 + len(range(first, m, every))
        pick = slice(first, m, every)
        truth = np.array(self.truth_rows, dtype=float).reshape(m, len(TRUTH_NAMES))
        est = np.array(self.est_rows, dtype=float).reshape(m, len(ESTIMATE_NAMES))
        act = np.array(self.act_rows, dtype=float).reshape(m, len(ACTUATION_NAMES))
        self.truth[r0:r1] = truth[pick]
        self.est[r0:r1] = est[pick]
        self.act[r0:r1] = act[pick]
        self.cmds[r0:r1] = np.array(self.cmd_rows[pick], dtype=float).reshape(r1 - r0, self.cmds.shape[1])
        self.push[r0:r1] = np.array(self.push_rows[pick], dtype=float).reshape(r1 - r0, len(PUSH_NAMES))
        if self.meas is not None:
            self.meas.put(r0, self.meas_rows[pick])
            bias = self.bias_rows[pick]
            self.bias[r0:r1] = np.nan
            where = [j for j, b in enumerate(bias) if b is not None]
            if where:
                self.bias[r0 + np.array(where)] = [bias[j] for j in where]
        if self.full is not None:
            rows = slice(s, s + m)
            f = self.full
            f["t"][rows] = truth[:, TRUTH_NAMES.index("t")]
            f["theta"][rows] = truth[:, TRUTH_NAMES.index("theta")]
            f["distance"][rows] = truth[:, TRUTH_NAMES.index("distance")]
            f["alpha"][rows] = truth[:, TRUTH_NAMES.index("alpha")]
            f["theta_est"][rows] = est[:, ESTIMATE_NAMES.index("theta_est")]
            f["torque_l"][rows] = act[:, ACTUATION_NAMES.index("torque_l")]
            f["torque_r"][rows] = act[:, ACTUATION_NAMES.index("torque_r")]
        for rows in (self.truth_rows, self.est_rows, self.cmd_rows, self.act_rows, self.push_rows, self.meas_rows,
                     self.bias_rows):
            rows.clear()
        self.start = s + m


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
