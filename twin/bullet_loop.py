"""A whole run on the PyBullet twin, logged as a :class:`twin.runs.Run`: :func:`simulate_twin`
drives :class:`twin.loop.ClosedLoop`.

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the ``ideal`` estimator passes the ground truth through), kept
as a reference.

Logged at the control rate, one row per control instant (see :mod:`twin.runs`).
"""
from __future__ import annotations

import math

import numpy as np

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.params import NOMINAL, RobotParams
from twin.plant.bullet import TwinConfig
from twin.runs import (ACTUATION_NAMES, COMMAND_NAMES, COMMAND_UNITS, ESTIMATE_NAMES, ESTIMATE_UNITS, PUSH_NAMES,
                       PUSH_UNITS, TRUTH_NAMES, Run, TwinRun)
from twin.sensors import Measurement, SensorConfig

__all__ = ["ACTUATION_NAMES", "COMMAND_NAMES", "COMMAND_UNITS", "ESTIMATE_NAMES", "ESTIMATE_UNITS", "PUSH_NAMES",
           "PUSH_UNITS", "Run", "TRUTH_NAMES", "TwinRun", "simulate_twin"]


def simulate_twin(controller, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator="ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None, estimator_params: dict | None = None) -> Run:
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
    if ideal and not (estimator in ("ekf", "ideal") if isinstance(estimator, str)
                      else getattr(estimator, "reads_truth", False)):
        raise TwinError(f"sensors=None is ideal sensing (the 'ideal' estimator reads the truth), so estimator "
                        f"{estimator!r} would not run; give sensors=SensorConfig(...) to use it")
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
        twin = loop.twin  # read directly below: this loop runs once per control period
        command, step = loop.command, loop.step
        for i in range(n_rows):
            if twin.status == "diverged":
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
            c = command()
            cmds.append(c)
            if i == n_ctrl or twin.status != "running":
                n = i + 1
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            step(c)
            act.append(twin.actuation)
            push.append(twin.push_force)
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
    return Run(t, truth, cmds, act, push, status, reason, config, experiment, controller_name,
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
