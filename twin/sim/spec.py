"""The run specification: everything one closed-loop run needs, typed and validated once.

A :class:`RunSpec` is what a scenario becomes for one controller
(:meth:`twin.scenarios.Scenario.run_spec`), what :func:`twin.sim.simulate.simulate` runs and
what the Gymnasium environments, ``twin check`` and the sweeps carry (through the scenario
runner). It holds no open resource: the plant, the sensors' generator and the loop are made
when a run starts, so one specification runs any number of times, and
``dataclasses.replace(spec, seed=7)`` (or another plant) is a new, re-validated one.

Units: SI throughout (rad, m, s, Hz, N·m); each field says its own.

Every check a run needs that does not need the run itself is made here, in
``__post_init__``, with a one-line :class:`~twin.errors.TwinError` naming the field and what
is allowed: the duration against the control period, the seed, the sensors' rates against
the control period, the logging options, and ideal sensing against the estimator.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from twin.errors import TwinError
from twin.limits import PluginLimits
from twin.params import NOMINAL, RobotParams
from twin.plant.base import TwinConfig
from twin.protocols import Targets, describe_object
from twin.registry import (PLANTS, BuildContext, build_controller, build_estimator, check_kind, check_plant, label,
                           plant_motor, resolve)
from twin.sim.recorder import check_log_every
from twin.sensors import SensorConfig
from twin.experiments import Experiment

LOG_FORMATS = ("csv", "csv.gz")  # trajectory.csv, or the same text gzip-compressed


def _finite(name: str, value, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value):
        raise TwinError(f"{name} must be a finite number in {unit}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class InitialState:
    """Where the robot starts, at rest: body pitch ``theta`` and heading ``alpha`` in rad, axle
    midpoint (``x``, ``y``) in m."""

    theta: float = 0.0
    alpha: float = 0.0
    x: float = 0.0
    y: float = 0.0

    def __post_init__(self):
        for name, unit in (("theta", "rad"), ("alpha", "rad"), ("x", "m"), ("y", "m")):
            object.__setattr__(self, name, _finite(f"initial {name}", getattr(self, name), unit))

    @property
    def position(self) -> tuple[float, float]:
        """(x, y) in m."""
        return (self.x, self.y)


@dataclass(frozen=True)
class Sensing:
    """How the estimator learns the state.

    ``true``: the IMU, encoders and faults the twin simulates (a
    :class:`~twin.sensors.SensorConfig`), or None: ideal sensing, nothing measured, and the
    ``ideal`` estimator passes the ground truth through. ``believed``: the sensors as the
    estimator believes them (its Q and R derive from it); None: the true specification."""

    true: SensorConfig | None = SensorConfig()
    believed: SensorConfig | None = None

    def __post_init__(self):
        for name in ("true", "believed"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, SensorConfig):
                raise TwinError(f"sensing.{name} must be a SensorConfig or None"
                                f"{' (ideal sensing)' if name == 'true' else ' (as the true one)'}, got {value!r}")
        if self.true is None and self.believed is not None:
            raise TwinError("sensing.believed needs simulated sensors: with ideal sensing (true=None) nothing is "
                            "measured, so there is nothing to believe")

    @property
    def ideal(self) -> bool:
        """Nothing measured: the controllers read the truth."""
        return self.true is None

    @property
    def as_believed(self) -> SensorConfig | None:
        """The specification the estimator is built for."""
        return self.believed if self.believed is not None else self.true


IDEAL_SENSING = Sensing(None)


@dataclass(frozen=True)
class Plugin:
    """A controller or an estimator of a run: a kind of :mod:`twin.registry` (a built-in name
    or ``"package.module:attribute"``) built with ``params`` for the run, or an object that
    meets :class:`twin.protocols.Controller` / :class:`twin.protocols.Estimator`, used as it
    is (its ``reset``/``start`` begins each run)."""

    kind: Any
    params: Mapping[str, Any] | None = None

    def __post_init__(self):
        if isinstance(self.kind, str) and not self.kind.strip():
            raise TwinError("a plugin kind must not be empty; allowed: a built-in name (see 'twin kinds') or "
                            "package.module:attribute")
        if self.params is not None and not isinstance(self.params, Mapping):
            raise TwinError(f"plugin parameters must be a table of keyword arguments, got {self.params!r}")
        if self.params is not None and not isinstance(self.kind, str):
            raise TwinError("plugin parameters are for a kind that is built for the run; an object is used as it is")

    @property
    def is_kind(self) -> bool:
        """A kind to build (True), or an object to use as it is (False)."""
        return isinstance(self.kind, str)


@dataclass(frozen=True)
class Logging:
    """What the run keeps: every ``every``-th control step (≥ 1; the metrics always come from
    every step), the estimator's ``diagnostics()`` at every step (needs ``every`` = 1: the
    filter's lagged states are matched to the truth step by step), and the trajectory file's
    ``format`` ("csv" or "csv.gz") when the run is written."""

    every: int = 1
    diagnostics: bool = False
    format: str = "csv"

    def __post_init__(self):
        object.__setattr__(self, "every", check_log_every(self.every))
        if not isinstance(self.diagnostics, bool):
            raise TwinError(f"logging.diagnostics must be true or false, got {self.diagnostics!r}")
        if self.every > 1 and self.diagnostics:
            raise TwinError(f"log_filter needs every control step (the filter's lagged states are matched to the "
                            f"truth step by step), so log_every must be 1 with it, got {self.every!r}")
        if self.format not in LOG_FORMATS:
            raise TwinError(f"log_format must be one of {', '.join(LOG_FORMATS)}, got {self.format!r}")


@dataclass(frozen=True)
class RunSpec:
    """One closed-loop run: plant → sensors → estimator → controller → actuators.

    Parameters
    ----------
    controller : Plugin or None
        What computes the wheel torques; None: whoever steps the loop gives them (a
        Gymnasium agent), and :func:`~twin.sim.simulate.simulate` refuses it.
    estimator : Plugin
        What turns the readings into the controller's estimate (default the EKF; with ideal
        sensing the ``ideal`` estimator, which reads the truth, whatever is given here as long
        as it is "ekf", "ideal" or an object declaring ``reads_truth = True``).
    plant : TwinConfig
        The true robot (Table III scaled), rates (physics and control, Hz), motors, floor and
        disturbances.
    plant_model : str or Plant
        A plant kind of :mod:`twin.registry`, built on ``plant`` for the run: ``"bullet"``
        (the PyBullet twin), ``"analytic"`` (equation (1), ideal torque sources) or one's own
        ``"package.module:attribute"``; or an object meeting :class:`twin.protocols.Plant`
        (its control rate is the run's).
    plant_params : mapping
        Keyword arguments for a plant kind of one's own (a scenario's ``[plant.params]``).
    initial : InitialState
        Pitch and heading (rad) and axle midpoint (m) at t = 0, at rest.
    targets : Targets
        Position p_d (m) and heading α_d (rad) given to the controller; None: that loop off.
    duration : float
        Simulated time in s, at least one control period.
    seed : int
        The run's seed (≥ 0): the sensors' noise and faults are drawn from it and nothing else.
    sensing : Sensing
        The simulated sensors (true and believed), or ideal sensing.
    model : RobotParams
        The robot the controllers and the estimator assume (the nominal model, Table III).
    design : callable or None
        Returns the LMI balance design the fuzzy cascades use (solved on first use; None:
        the default design of :mod:`twin.controllers.designs` on ``model``).
    options : mapping
        The fuzzy cascades' options (``fou``, ``type_reduction``, ``psi_error_limit``).
    logging : Logging
        What the run keeps.
    name, description : str
        The run's name (the scenario's) and description, recorded with the run.
    label : str
        The controller's name in the run's log (a kind: "it2"); default the kind, if one.
    limits : PluginLimits or None
        What the controller and the estimator may cost (wall time per step and per run,
        memory growth per run; :mod:`twin.limits`); None: no limits. Not the plant's: the
        same robot runs a plugin with limits or without.
    """

    controller: Plugin | None
    estimator: Plugin = Plugin("ekf")
    plant: TwinConfig = field(default_factory=TwinConfig)
    plant_model: Any = "bullet"
    plant_params: Mapping[str, Any] = field(default_factory=dict)
    initial: InitialState = InitialState()
    targets: Targets = Targets()
    duration: float = 15.0
    seed: int = 0
    sensing: Sensing = Sensing()
    model: RobotParams = NOMINAL
    design: Callable | None = field(default=None, repr=False, compare=False)
    options: Mapping[str, Any] = field(default_factory=dict)
    logging: Logging = Logging()
    name: str = ""
    description: str = ""
    label: str = ""
    limits: PluginLimits | None = None

    def __post_init__(self):
        for name, kind, what in (("controller", Plugin, "twin.sim.spec.Plugin(kind, params) or None"),
                                 ("estimator", Plugin, "twin.sim.spec.Plugin(kind, params)"),
                                 ("plant", TwinConfig, "twin.plant.base.TwinConfig"),
                                 ("initial", InitialState, "twin.sim.spec.InitialState"),
                                 ("targets", Targets, "twin.protocols.Targets(position, heading)"),
                                 ("sensing", Sensing, "twin.sim.spec.Sensing(true, believed)"),
                                 ("model", RobotParams, "twin.params.RobotParams"),
                                 ("logging", Logging, "twin.sim.spec.Logging"),
                                 ("limits", PluginLimits, "twin.limits.PluginLimits or None")):
            value = getattr(self, name)
            if not (isinstance(value, kind) or (name in ("controller", "limits") and value is None)):
                raise TwinError(f"RunSpec.{name} must be a {what}, got {value!r}")
        if isinstance(self.plant_model, str):
            check_kind("plant", self.plant_model)
        else:
            check_plant(self.plant_model, not self.sensing.ideal)
        if not isinstance(self.plant_params, Mapping):
            raise TwinError(f"RunSpec.plant_params must be a table of keyword arguments, got {self.plant_params!r}")
        rate = self.control_rate
        duration = self.duration
        if isinstance(duration, bool) or not isinstance(duration, (int, float, np.floating, np.integer)) \
                or not (math.isfinite(duration) and duration >= 1.0 / rate):
            raise TwinError(f"duration must be at least one control period ({1.0 / rate:g} s), got "
                            f"{duration if isinstance(duration, (int, float)) else repr(duration)} s")
        object.__setattr__(self, "duration", float(duration))
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise TwinError(f"seed must be a non-negative integer, got {seed!r}")
        if not self.sensing.ideal:
            self.sensing.true.steps(rate)  # rates and latencies fit the control period
        if self.sensing.ideal:
            e = self.estimator.kind
            if not (e in ("ekf", "ideal") if isinstance(e, str) else getattr(e, "reads_truth", False)):
                raise TwinError(f"sensors=None is ideal sensing (the 'ideal' estimator reads the truth), so "
                                f"estimator {e!r} would not run; give sensors=SensorConfig(...) to use it")
        if not isinstance(self.options, Mapping):
            raise TwinError(f"RunSpec.options must be a table of the cascades' options, got {self.options!r}")

    # ---- what follows from the specification --------------------------------------------------
    @property
    def control_rate(self) -> float:
        """Hz: the plant object's, else the configuration's."""
        if isinstance(self.plant_model, str):
            return float(self.plant.control_rate)
        return float(self.plant_model.control_rate)

    @property
    def control_steps(self) -> int:
        """Control periods in :attr:`duration`."""
        return int(round(self.duration * self.control_rate))

    @property
    def motor(self):
        """The motors the controllers and the estimator may know of: the configuration's, for a
        plant that applies them (:class:`twin.protocols.Plant`'s ``applies_motor``: the PyBullet
        twin); None (ideal torque sources) for one that does not say so."""
        m = self.plant_model
        if isinstance(m, str):
            return plant_motor(m, self.plant)
        return m.config.motor if getattr(m, "applies_motor", False) and isinstance(
            getattr(m, "config", None), TwinConfig) else None

    @property
    def plant_name(self) -> str:
        """The plant as the run records it: a built-in kind's label ("twin" for the PyBullet
        twin, "analytic"), a plant kind of one's own as named, a plant object's class; a
        built-in's object as its kind."""
        m = self.plant_model
        if isinstance(m, str):
            return label(m) if m in PLANTS else m
        for kind in PLANTS:
            if type(m) is resolve("plant", kind)[0]:
                return label(kind)
        return describe_object(m)

    @property
    def sensing_name(self) -> str:
        """The estimator's name as the run records it."""
        e = self.estimator.kind
        if self.sensing.ideal:
            return "ideal"
        return e if isinstance(e, str) else getattr(e, "name", type(e).__name__)

    @property
    def experiment(self):
        """The run's task as :class:`twin.sim.runs.Run` records it (:class:`twin.experiments.Experiment`)."""
        t = self.targets
        return Experiment(self.name, self.description, theta0=self.initial.theta, p_d=t.position, alpha_d=t.heading,
                          duration=self.duration)

    def context(self) -> BuildContext:
        """The :class:`twin.registry.BuildContext` the controller and the estimator are built with
        (the one place a run's build context is made)."""
        return BuildContext(self.control_rate, self.model, self.motor, self.sensing.as_believed, self.targets,
                            self.initial.alpha, self.design, dict(self.options))

    def build_plugins(self, controller: bool = True, estimator: bool = True, named=None) -> dict:
        """The run's controller and estimator (``controller``/``estimator``: which are wanted),
        role → object: an object given is used as it is, a kind is built for this run with its
        parameters (the ``ideal`` estimator with ideal sensing, unless an object that reads the
        truth was given). The one place a run's plugins are built: the context is made once,
        and the registry builds them one after the other.

        ``named(role, error)``: what a plugin that cannot be built raises instead of the
        registry's one-line :class:`~twin.errors.PluginError` (a scenario names its key)."""
        if controller and self.controller is None:
            raise TwinError("this run has no controller (RunSpec.controller is None): give one, or step the loop "
                            "with commands")
        e, c = self.estimator, self.controller
        wanted = []
        if estimator:
            wanted.append(("estimator", e.kind if (not e.is_kind and not self.sensing.ideal) else None,
                           "ideal" if self.sensing.ideal else e.kind, e.params))
        if controller:
            wanted.append(("controller", None if c.is_kind else c.kind, c.kind, c.params))
        context = self.context() if any(obj is None for _, obj, _, _ in wanted) else None
        built = {}
        for role, obj, kind, params in wanted:
            if obj is None:
                try:
                    obj = (build_estimator if role == "estimator" else build_controller)(kind, params, context)
                except TwinError as exc:
                    if named is None:
                        raise
                    raise named(role, exc) from None
            built[role] = obj
        return built

    def built(self, named=None) -> "RunSpec":
        """This specification with its controller (if any) and estimator built for one run
        (:meth:`build_plugins`), so that a plugin that cannot be built is said before anything
        runs. The fields are validated already: the copy is not validated again."""
        made = self.build_plugins(self.controller is not None, True, named)
        spec = copy.copy(self)
        object.__setattr__(spec, "estimator", Plugin(made["estimator"]))
        if "controller" in made:
            object.__setattr__(spec, "controller", Plugin(made["controller"]))
        return spec

    def build_controller(self, context=None):
        """The controller of this run: the object given, or the kind built (a one-line
        :class:`~twin.errors.PluginError` if it cannot be); ``context``: the one to build it
        with (default :meth:`context`)."""
        if context is None or not (self.controller is not None and self.controller.is_kind):
            return self.build_plugins(True, False)["controller"]
        return build_controller(self.controller.kind, self.controller.params, context)

    def build_estimator(self, context=None):
        """The estimator of this run (the ``ideal`` one with ideal sensing, unless an object that
        reads the truth was given); ``context``: the one to build it with (default :meth:`context`)."""
        e = self.estimator
        if context is None or (not e.is_kind and not self.sensing.ideal):
            return self.build_plugins(False, True)["estimator"]
        return build_estimator("ideal" if self.sensing.ideal else e.kind, e.params, context)


__all__ = ["IDEAL_SENSING", "InitialState", "LOG_FORMATS", "Logging", "Plugin", "RunSpec", "Sensing",
           "check_log_every"]
