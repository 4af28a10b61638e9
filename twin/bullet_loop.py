"""A whole run, logged as a :class:`twin.runs.Run`: :func:`simulate_twin` drives
:class:`twin.loop.ClosedLoop` on the PyBullet twin (by default) or on any
:class:`twin.protocols.Plant` (``plant``: "analytic" for equation (1), or one's own object).

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the ``ideal`` estimator passes the ground truth through), kept
as a reference.

Logged at the control rate, one row per control instant (see :mod:`twin.runs`), or at
every N-th instant (``log_every``), by a :class:`twin.recorder.Recorder` fed what the loop
publishes (its step results and the commands), never the loop's internals. Memory: the
step results are gathered for a chunk of :data:`CHUNK` control steps at a time, then
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
from twin.recorder import Recorder, check_log_every
from twin.runs import (ACTUATION_NAMES, COMMAND_NAMES, COMMAND_UNITS, ESTIMATE_NAMES, ESTIMATE_UNITS, PUSH_NAMES,
                       PUSH_UNITS, TRUTH_NAMES, Run, TwinRun)
from twin.sensors import SensorConfig

CHUNK = 4096  # control steps gathered before they move into the log's arrays (twin.recorder.Recorder's chunk)

__all__ = ["ACTUATION_NAMES", "COMMAND_NAMES", "COMMAND_UNITS", "ESTIMATE_NAMES", "ESTIMATE_UNITS", "PUSH_NAMES",
           "PUSH_UNITS", "Run", "TRUTH_NAMES", "TwinRun", "check_log_every", "simulate_twin"]


def simulate_twin(controller, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator="ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None, estimator_params: dict | None = None, log_every: int = 1, plant=None) -> Run:
    """Run ``controller`` on a new twin built from ``config`` (or on ``plant``) from the experiment's θ0.

    A driver of :class:`twin.loop.ClosedLoop`: reset, then the controller's command and a
    step per control period, each step's result handed to a :class:`twin.recorder.Recorder`
    (see the module docstring).

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
    rec = Recorder.for_loop(loop, n_ctrl + 1, log_every=every, diagnostics=log_filter, chunk=CHUNK)
    instant, period = rec.instant, rec.period
    diagnostics = loop.diagnostics if log_filter else None
    with loop:
        res = loop.reset(seed)
        command, step = loop.command, loop.step
        for i in range(n_ctrl + 1):
            if res.status == "diverged":  # the non-finite state is not logged: the log ends with the last finite one
                break
            d = None if diagnostics is None else diagnostics()
            c = command()
            instant(res, c, d)
            if i == n_ctrl or res.status != "running":
                break
            if progress is not None and i % report_every == 0 and i:
                progress(i, n_ctrl)
            res = step(c)
            period(res)  # what the motors and pushes did over [t_i, t_i+1)
        status = "ok" if loop.status == "running" else loop.status
        reason = "" if status == "ok" else loop.end_reason
        stats = {} if ideal else loop.estimator_stats()
        sensor_counts = {} if ideal else loop.sensor_counts()
        sensor_truth = {} if ideal else loop.sensor_truth()
        if progress is not None:
            progress(n_ctrl, n_ctrl)
    units = {**COMMAND_UNITS, **getattr(controller, "signal_units", {})}
    return rec.run(status, reason, config, command_units=tuple(units.get(k, "1") for k in rec.command_names),
                   experiment=experiment, controller=controller_name, sensing=sensing, estimator_stats=stats,
                   sensor_counts=sensor_counts, seed=None if ideal else int(seed), sensor_truth=sensor_truth,
                   sensor_config=sensors, model_params=model_params, plant=plant_name)
