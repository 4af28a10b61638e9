"""A whole run, logged as a :class:`twin.sim.runs.Run`: :func:`simulate_twin` drives
:class:`twin.sim.loop.ClosedLoop` on the PyBullet twin (by default) or on any
:class:`twin.protocols.Plant` (``plant``: "analytic" for equation (1), or one's own object).

Sensing. By default the controllers act on the estimator's output, computed from the
simulated IMU and encoders (:mod:`twin.sensors`, :mod:`estimation`); ``sensors=None``
asks for ideal sensing (the ``ideal`` estimator passes the ground truth through), kept
as a reference.

Logged at the control rate, one row per control instant (see :mod:`twin.sim.runs`), or at
every N-th instant (``log_every``), by a :class:`twin.sim.recorder.Recorder` fed what the loop
publishes (its step results and the commands), never the loop's internals. Memory: the
step results are gathered for a chunk of :data:`CHUNK` control steps at a time, then
moved into preallocated float64 arrays, so a run costs about 8 bytes per logged number
(some 0.27 GB per simulated hour at 200 Hz with sensors, every step logged).
"""
from __future__ import annotations

from twin.errors import TwinError
from twin.experiments import Experiment
from twin.limits import PluginLimits
from twin.params import NOMINAL, RobotParams
from twin.plant.base import TwinConfig
from twin.sim.recorder import check_log_every
from twin.sim.runs import (ACTUATION_NAMES, COMMAND_NAMES, COMMAND_UNITS, ESTIMATE_NAMES, ESTIMATE_UNITS, PUSH_NAMES,
                       PUSH_UNITS, TRUTH_NAMES, Run, TwinRun)
from twin.sensors import SensorConfig
from twin.sim.simulate import CHUNK, simulate
from twin.sim.spec import InitialState, Logging, Plugin, RunSpec, Sensing

__all__ = ["ACTUATION_NAMES", "COMMAND_NAMES", "COMMAND_UNITS", "ESTIMATE_NAMES", "ESTIMATE_UNITS", "PUSH_NAMES",
           "PUSH_UNITS", "Run", "TRUTH_NAMES", "TwinRun", "check_log_every", "simulate_twin"]


def simulate_twin(controller, experiment: Experiment, config: TwinConfig | None = None,
                  duration: float | None = None, controller_name: str = "", alpha0: float = 0.0,
                  position=(0.0, 0.0), sensors: SensorConfig | None = SensorConfig(), estimator="ekf",
                  seed: int = 0, model_params: RobotParams = NOMINAL, log_filter: bool = False,
                  progress=None, estimator_params: dict | None = None, log_every: int = 1, plant=None,
                  limits: PluginLimits | None = None) -> Run:
    """Run ``controller`` on a new twin built from ``config`` (or on ``plant``) from the experiment's θ0.

    A driver of :class:`twin.sim.loop.ClosedLoop`: reset, then the controller's command and a
    step per control period, each step's result handed to a :class:`twin.sim.recorder.Recorder`
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
        (``Run.full_rate``), so :func:`twin.outputs.metrics.run_metrics` gives the same figures for
        every N. N > 1 excludes ``log_filter`` (the EKF's consistency checks need every step).
    limits : PluginLimits or None
        What the controller and the estimator may cost (:mod:`twin.limits`); None: no limits.

    The twin (the plant) is closed when the run ends, fallen or not.
    """
    config = config if config is not None else TwinConfig()
    if plant is not None and not isinstance(plant, str):
        own = getattr(plant, "config", None)
        config = own if isinstance(own, TwinConfig) else config
    if sensors is not None and not isinstance(sensors, SensorConfig):
        raise TwinError(f"sensors must be a SensorConfig or None (ideal sensing), got {sensors!r}")
    spec = RunSpec(
        controller=Plugin(controller), plant=config, plant_model="bullet" if plant is None else plant,
        estimator=Plugin(estimator, estimator_params if isinstance(estimator, str) else None),
        initial=InitialState(experiment.theta0, alpha0, *position), targets=experiment.targets,
        duration=experiment.duration if duration is None else duration, seed=seed, sensing=Sensing(sensors),
        model=model_params, logging=Logging(log_every, log_filter), name=experiment.name,
        description=experiment.description, label=controller_name, limits=limits)
    return simulate(spec, progress)
