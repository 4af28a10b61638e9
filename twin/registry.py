"""The one registry of plant, controller and estimator kinds: built-in names and import paths.

A *kind* is either a built-in name (:data:`PLANTS`, :data:`CONTROLLERS`, :data:`ESTIMATORS`)
or an import path ``"package.module:attribute"`` naming a user's class or factory function. Every
place that accepts a kind (the Python API, scenario files, ``twin run --controller``,
``twin sweep``, the Gymnasium environment) resolves it here, so the kind strings live
here alone.

Building one (:func:`build_controller`, :func:`build_estimator`): a built-in's factory,
or the imported attribute, is called with the parameters as keyword arguments (a
scenario's ``[controller.params.KIND]`` or ``[sensors.estimator_params]`` table), plus
``context=`` (a :class:`BuildContext`: control rate, model, motor, sensors, targets,
initial heading, balance design) if its signature has a parameter named ``context``.
The result must meet :class:`twin.protocols.Controller` or
:class:`twin.protocols.Estimator`; anything that goes wrong is one
:class:`~twin.errors.PluginError` line naming the kind and what was expected.

A plant (:func:`build_plant`) is built from the robot instead: ``factory(config, theta0,
alpha0, position, **params)``, ``config`` a :class:`~twin.plant.base.TwinConfig`, the pose
in rad and m (a scenario's ``plant.model`` and ``[plant.params]``); the result must meet
:class:`twin.protocols.Plant` (:func:`check_plant`).

An import path runs that module's code, with the user's rights, exactly as
``python -c "import package.module"`` would. :func:`provenance` records the module, its
file and the file's SHA-256 so a result can be traced to the code that produced it.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from twin import limits as _limits
from twin.errors import MAY_NOT_END, PluginError, TwinError, ends_process, raised_text
from twin.params import NOMINAL, RobotParams
from twin.plant.base import TwinConfig
from twin.protocols import (ACTUATION_NAMES, ESTIMATE_NAMES, PUSH_NAMES, TRUTH_NAMES, Targets, describe_object,
                            one_line, shown)

EXPORT_PREFIX = "export:"  # "export:DIR": the C of an export directory (twin export), compiled and run in the loop
_IMPORT_PATH = re.compile(r"^[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*$")


@dataclass(frozen=True)
class Kind:
    """A built-in kind: its display ``label``, a one-line ``description``, the ``factory``
    called as ``factory(context, **params)``, and whether it uses the LMI balance design."""

    name: str
    label: str
    description: str
    factory: Callable | None = field(repr=False)
    uses_design: bool = False
    parameters: tuple = ()  # the keyword parameters a scenario may give it
    path: str = ""  # "package.module:attribute": the factory, imported on first use (factory None)


def _nominal():
    return NOMINAL


@dataclass(frozen=True)
class BuildContext:
    """What a factory may use to build a controller or an estimator for one run.

    ``control_rate`` Hz; ``model`` the :class:`~twin.params.RobotParams` the controllers and
    the estimator assume (the nominal model, not the twin's true plant); ``motor`` the
    motors' :class:`~twin.actuators.DCMotorParams` (None: ideal torque sources);
    ``sensors`` the :class:`~twin.sensors.SensorConfig` as the estimator believes it (None:
    ideal sensing; a scenario's ``[sensors.believed]``, while the twin simulates the true one),
    from which the EKF's Q and R derive;
    ``targets`` the run's :class:`~twin.protocols.Targets`; ``alpha0`` the initial heading
    in rad; ``design`` a zero-argument callable returning the LMI balance design
    (:class:`~twin.controllers.lmi.BalanceDesign`, solved on first use); ``options`` the
    scenario's controllers' options (``fou``, ``type_reduction``, ``psi_error_limit``, and for another robot than the paper's ``universes`` and ``rho``: see :meth:`twin.scenarios.Scenario.cascade_options`).
    """

    control_rate: float = 200.0
    model: Any = field(default_factory=_nominal)
    motor: Any = None
    sensors: Any = None
    targets: Targets = Targets()
    alpha0: float = 0.0
    design: Callable | None = field(default=None, repr=False)
    options: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.model, RobotParams):
            raise TwinError(f"BuildContext.model must be a twin.params.RobotParams (the model the controllers "
                            f"and the estimator assume; default the nominal one), got {shown(self.model)}")

    def balance_design(self):
        """The LMI balance design: ``design()``, or (None) the design store's default design on
        :attr:`model` (solved once per process, or read from the disk cache)."""
        if self.design is None:
            # optional: the design store (and the LMI modules) only when no design was given
            from twin.controllers.designs import balance_design

            return balance_design(self.model)
        return self.design()


# ---- built-in controllers --------------------------------------------------------------------
# Each factory imports its kind's code when that kind is built (optional dependencies: a run of
# LQR does not load the fuzzy cascade, nor a run of a user's estimator the EKF).
def _cascade(kind: str):
    def build(ctx: BuildContext, fou=None, type_reduction=None, psi_error_limit=None, universes=None):
        # optional: the fuzzy cascade's code only when a fuzzy controller is built
        from twin.controllers.cascade import build_cascade
        from twin.fuzzy.mamdani import TYPE_REDUCERS

        o = dict(ctx.options)
        for name, value in (("fou", fou), ("type_reduction", type_reduction), ("psi_error_limit", psi_error_limit),
                            ("universes", universes)):
            if value is not None:
                o[name] = value
        # checked here, not only where used: a loop that a run leaves off must not hide a bad value
        if not (isinstance(o.get("fou", 0.25), (int, float)) and 0.0 <= o.get("fou", 0.25) < 0.5):
            raise TwinError(f"fou must be a number in [0, 0.5), got {shown(o['fou'])}")
        if o.get("type_reduction", "bmm") not in TYPE_REDUCERS:
            raise TwinError(f"type_reduction must be one of {', '.join(TYPE_REDUCERS)}, got {shown(o['type_reduction'])}")
        return build_cascade(kind, ctx.balance_design(), ctx.targets, ctx.model, **o)
    return build


def _lqr(ctx: BuildContext, **params):
    from twin.controllers.lqr import build_lqr  # optional: only when an LQR controller is built

    return build_lqr(ctx, **params)


CONTROLLERS: dict[str, Kind] = {
    "it2": Kind("it2", "IT2", "the paper's IT2 fuzzy cascade: IT2 PDC balance (LMI gains), IT2 Mamdani position "
                "and direction controllers, BMM type reduction", _cascade("it2"), uses_design=True,
                parameters=("fou", "type_reduction", "psi_error_limit", "universes")),
    "t1": Kind("t1", "type-1", "the type-1 fuzzy cascade of the same structure and gains", _cascade("t1"),
               uses_design=True, parameters=("fou", "type_reduction", "psi_error_limit", "universes")),
    "lqr": Kind("lqr", "LQR", "LQR on the linearised nominal model (TS rule 1), Bryson's rule; LQR heading loop",
                _lqr, parameters=("psi_error_limit", "state_scales", "input_scale", "yaw_state_scales",
                                  "yaw_input_scale", "control_period")),
}


# ---- built-in estimators ---------------------------------------------------------------------
def _needs_sensors(kind: str, ctx: BuildContext):
    if ctx.sensors is None:
        raise PluginError(f"estimator {shown(kind)} needs sensors, but sensing is ideal; use estimator 'ideal' or "
                          "give a SensorConfig")
    return ctx.sensors


def _ekf(ctx: BuildContext, compiled=None, **params):
    # optional: the EKF's code only when an EKF is built
    from estimation.ekf import EKFEstimator
    from estimation.model import EstimatorModel

    sensors = _needs_sensors("ekf", ctx)
    every, d_imu, d_enc = sensors.steps(ctx.control_rate)
    model = EstimatorModel(ctx.model, ctx.motor, sensors.imu, sensors.encoders, ctx.control_rate)
    return EKFEstimator(model, every, d_imu, d_enc, alpha0=ctx.alpha0, compiled=compiled, **params)


def _baseline(kind: str):
    def build(ctx: BuildContext, **params):
        from estimation.baselines import AngleBiasKalman, ComplementaryFilter  # optional: only when built

        _needs_sensors(kind, ctx)
        cls = ComplementaryFilter if kind == "complementary" else AngleBiasKalman
        return cls(ctx.control_rate, ctx.model.r, ctx.model.b, ctx.alpha0, **params)
    return build


def _ideal(ctx: BuildContext):
    from estimation.ideal import IdealEstimator  # optional: only when built

    return IdealEstimator()


ESTIMATORS: dict[str, Kind] = {
    "ekf": Kind("ekf", "EKF", "the strapdown extended Kalman filter (IMU-driven, encoder-corrected, gated)", _ekf,
                parameters=("compiled", "consider", "gate_probability", "learn_time", "max_rejects_in_row",
                            "model_uncertainty")),
    "complementary": Kind("complementary", "complementary", "complementary filter (a = 0.98) with odometry",
                          _baseline("complementary"), parameters=("a",)),
    "kalman2": Kind("kalman2", "kalman2", "two-state angle-and-bias Kalman filter (TKJ Electronics) with odometry",
                    _baseline("kalman2"), parameters=("q_angle", "q_bias", "r_measure")),
    "ideal": Kind("ideal", "ideal", "the ground truth passed through (a reference, not an estimator)", _ideal),
}


# ---- built-in plants: classes by import path, as a user's plant is named -------------------------
PLANTS: dict[str, Kind] = {
    # the label is the plant's name in a run's record ("twin": the PyBullet twin)
    "bullet": Kind("bullet", "twin", "the PyBullet twin: contact, friction, DC motors with PWM drivers, "
                   "disturbances", None, path="twin.plant.bullet:BulletTwin"),
    "analytic": Kind("analytic", "analytic", "equation (1) by RK4 at the physics rate: ideal torque sources, "
                     "rolling without slip on a level floor", None, path="twin.plant.analytic_plant:AnalyticPlant"),
}

_ROLES = {"controller": CONTROLLERS, "estimator": ESTIMATORS, "plant": PLANTS}
_ROLE_CODES = {"controller": 1, "estimator": 2, "plant": 3}  # twin.limits.ROLES' codes
_METHODS = {"controller": ("reset", "__call__"), "estimator": ("start", "step"), "plant": ("reset", "step", "close")}
_SIGNATURES = {"controller": "reset(targets) and __call__(estimate, targets)",
               "estimator": "start(measurement) and step(measurement, command)",
               "plant": "reset(theta0, alpha0, position), step(ul, ur) and close()"}
_PLANT_ATTRIBUTES = ("control_rate",)
_SENSOR_ATTRIBUTES = ("kinematics", "com_local", "gravity")  # what the simulated IMU reads of a plant


def uses_design(kind: str) -> bool:
    """True for a built-in controller that uses the LMI balance design (a plugin asks for it
    through its context, if it wants it)."""
    return kind in CONTROLLERS and CONTROLLERS[kind].uses_design


def plugin_dirs(kinds) -> tuple[str, ...]:
    """The directories that hold the modules of the import-path ``kinds`` (for sys.path in workers)."""
    dirs = []
    for role, kind in kinds:
        p = provenance(role, kind)
        if p is not None and p["file"] and p["module"]:
            d = Path(p["file"]).parent
            # a package's module: the directory above the top-level package
            for _ in range(p["module"].count(".") + (Path(p["file"]).name == "__init__.py")):
                d = d.parent
            if str(d) not in dirs:
                dirs.append(str(d))
    return tuple(dirs)


def use_plugin_dirs(dirs) -> None:
    """Put ``dirs`` (from :func:`plugin_dirs`) first on ``sys.path``: a spawned worker or a Ray
    task then imports the same plugin files as the process that planned the work."""
    for path in reversed(tuple(dirs)):
        if path not in sys.path:
            sys.path.insert(0, path)


def is_import_path(kind: str) -> bool:
    """True for ``"package.module:attribute"``."""
    return isinstance(kind, str) and bool(_IMPORT_PATH.match(kind)) and not is_export(kind)


def is_user_code(kind) -> bool:
    """True for a kind that runs a user's code: an import path, or an export directory's C (which
    may have been edited since the export): such a kind runs in a worker process the command can
    stop (:mod:`twin.containment`), and its code's digest is part of what a run records."""
    return is_import_path(kind) or is_export(kind)


def is_export(kind) -> bool:
    """True for ``"export:DIR"``: the controllers or the estimator of an export directory
    (``twin export``), compiled with the host's C compiler and run in the twin's loop."""
    return isinstance(kind, str) and kind.startswith(EXPORT_PREFIX) and len(kind) > len(EXPORT_PREFIX)


def exported_kind(kind: str) -> str | None:
    """For ``"export:DIR"``: the built-in controller kind the export was made from (its manifest's
    ``controller``, e.g. ``"it2"``), None if DIR holds no readable export; None for any other kind."""
    if not is_export(kind):
        return None
    import json  # only: an export's manifest, read for its controller's kind

    try:
        doc = json.loads((Path(kind[len(EXPORT_PREFIX):]) / "export.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    c = doc.get("controller") if isinstance(doc, dict) else None
    return c if isinstance(c, str) else None


def _export_parameters(role: str) -> tuple:
    # the controllers' drive: "duty" (the C's driver law sets the PWM duties) or "torque" (the twin's does)
    return ("drive",) if role == "controller" else ()


def _exported(role: str, kind: str):
    directory = kind[len(EXPORT_PREFIX):]

    def build(ctx: BuildContext, **params):
        # optional: the export's loader (ctypes, the host's compiler) only for an export:DIR kind
        from twin.export import sil

        return (sil.build_controller if role == "controller" else sil.build_estimator)(directory, ctx, **params)
    return build


def check_kind(role: str, kind) -> str:
    """``kind`` if it is a built-in name or a well-formed import path; else a one-line error."""
    table = _ROLES[role]
    if isinstance(kind, str) and (kind in table or is_import_path(kind) or (role != "plant" and is_export(kind))):
        return kind
    raise PluginError(f"{role} {shown(kind)} is neither a built-in ({', '.join(table)}) nor an import path "
                      "'package.module:attribute'" + ("" if role == "plant" else " nor an export 'export:DIR'"))


def label(kind: str) -> str:
    """The display name: the built-in's label, or the attribute of an import path."""
    for table in _ROLES.values():
        if kind in table:
            return table[kind].label
    return kind.rsplit(":", 1)[-1] if is_import_path(kind) else kind


def resolve(role: str, kind: str) -> tuple[Callable, bool]:
    """(factory, is_plugin): the built-in's factory, or the imported attribute."""
    kind = check_kind(role, kind)
    table = _ROLES[role]
    if is_export(kind):
        return _exported(role, kind), False
    if kind in table:
        built_in = table[kind]
        if built_in.factory is not None:
            return built_in.factory, False
        module_name, attr = built_in.path.split(":", 1)
        return getattr(importlib.import_module(module_name), attr), False
    module_name, attr = kind.split(":", 1)
    try:
        _limits.mark(_ROLE_CODES[role], _limits.IMPORTING)
        try:
            module = _import(module_name)
        finally:
            _limits.unmark()
    except ModuleNotFoundError as exc:
        where = "" if exc.name == module_name else f" (it imports {shown(exc.name)}, which is missing)"
        raise PluginError(f"{role} {shown(kind)}: no module named {shown(module_name)}{where}; the module must be importable "
                          f"(on sys.path, installed, in the current directory or beside the scenario file)") from None
    except _limits.PLUGIN_FAILURES as exc:  # a plugin's import error is the user's, reported in one line
        raise PluginError(f"{role} {shown(kind)}: importing {shown(module_name)} failed: {raised_text(exc)}"
                          + (f"; {MAY_NOT_END}" if ends_process(exc) else "")) from None
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise PluginError(f"{role} {shown(kind)}: module {shown(module_name)} has no attribute {shown(attr)}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise PluginError(f"{role} {shown(kind)}: {shown(attr)} is a {type(obj).__name__}, not a class or factory function; "
                          f"expected a class (or function) returning an object with {_SIGNATURES[role]}")
    return obj, True


_BESIDE: list[str] = []  # the directories of the scenario files loaded in this process, in order


def look_beside(directory) -> None:
    """Let plugin modules be found in ``directory`` (a scenario file's), after sys.path and
    the current directory: a scenario's plugins may lie beside it, wherever it is run from."""
    d = str(Path(directory).resolve())
    if d not in _BESIDE:
        _BESIDE.append(d)


def _import(module_name: str):
    """Import ``module_name``; if it is not found, look in the current directory too, then
    beside the scenario files loaded (:func:`look_beside`), each after everything on
    sys.path, so it shadows nothing, as ``python -m`` would with the current directory."""
    import os

    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        # the module, or one it imports (a lab's controller beside its scenario importing a helper
        # module in the current directory), is looked for in these too, each added to what was added
        # before: a module found in one may import from another
        added, last = [], exc
        for d in [os.getcwd(), *_BESIDE]:
            if d in sys.path:
                continue
            sys.path.append(d)
            added.append(d)
            try:
                return importlib.import_module(module_name)
            except ModuleNotFoundError as again:
                last = again
        for d in added:
            sys.path.remove(d)
        raise last from None


def _accepts_context(factory) -> bool:
    try:
        return "context" in inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return False


def _build(role: str, kind: str, params: dict | None, context: BuildContext | None):
    factory, plugin = resolve(role, kind)
    if params is not None and not isinstance(params, dict):
        raise PluginError(f"{role} {shown(kind)}: parameters must be a table of keyword arguments, got {shown(params)}")
    params = dict(params or {})
    context = context if context is not None else BuildContext()
    if not plugin:
        allowed = _export_parameters(role) if is_export(kind) else _ROLES[role][kind].parameters
        unknown = [p for p in params if p not in allowed]
        if unknown:
            raise PluginError(f"{role} {shown(kind)}: unknown parameter{'s' * (len(unknown) > 1)} "
                              f"{', '.join(map(repr, unknown))}; allowed: {', '.join(allowed) or 'none'}")
    try:
        if not plugin:
            obj = factory(context, **params)
        else:
            _limits.mark(_ROLE_CODES[role], _limits.BUILDING)
            try:
                obj = factory(**params, context=context) if _accepts_context(factory) else factory(**params)
            finally:
                _limits.unmark()
    except PluginError:
        raise
    except TypeError as exc:
        allowed = (_export_parameters(role) if is_export(kind) else _ROLES[role][kind].parameters) if not plugin \
            else _parameters(factory)
        raise PluginError(f"{role} {shown(kind)}: cannot be built with parameters {shown(params)} "
                          f"({one_line(exc)}); allowed parameters: {', '.join(allowed) or 'none'}") from None
    except TwinError as exc:
        raise PluginError(f"{role} {shown(kind)}: {exc}") from None
    except _limits.PLUGIN_FAILURES as exc:  # the plugin's own failure, in one line
        raise PluginError(f"{role} {shown(kind)}: building it raised {raised_text(exc)}"
                          + (f"; {MAY_NOT_END}" if ends_process(exc) else "")) from None
    check_protocol(role, kind, obj)
    return obj


def _parameters(factory) -> tuple[str, ...]:
    """The keyword parameters of a plugin's class or factory (``context`` left out)."""
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        return ()
    skip = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    return tuple(n for n, p in sig.parameters.items() if n not in ("self", "context") and p.kind not in skip)


def check_protocol(role: str, kind: str, obj) -> None:
    """A one-line PluginError unless ``obj`` has the protocol's methods."""
    missing = [m for m in _METHODS[role] if not callable(getattr(obj, m, None))]
    if missing:
        raise PluginError(f"{role} {shown(kind)}: {describe_object(obj)} has no {' or '.join(f'{m}()' for m in missing)}; "
                          f"{'an' if role[0] in 'aeiou' else 'a'} {role} needs {_SIGNATURES[role]} "
                          f"(see twin.protocols.{role.capitalize()})")
    if role == "controller":
        signals = getattr(obj, "signals", ())
        if not (isinstance(signals, (tuple, list)) and all(isinstance(s, str) and s.isidentifier() for s in signals)):
            raise PluginError(f"{role} {shown(kind)}: 'signals' must be a tuple of names (identifiers) of extra logged "
                              f"signals, got {shown(signals)}")
        taken = set(TRUTH_NAMES + ESTIMATE_NAMES + ACTUATION_NAMES + PUSH_NAMES + ("ul_cmd", "ur_cmd"))
        clash = sorted({s for s in signals if s in taken or list(signals).count(s) > 1})
        if clash:
            raise PluginError(f"{role} {shown(kind)}: signal names {', '.join(map(repr, clash))} repeat each other or a "
                              "logged column (truth, estimate, command, actuation, push); choose other names")


def build_controller(kind: str, params: dict | None = None, context: BuildContext | None = None):
    """A controller of ``kind`` (built-in name or import path) meeting the Controller protocol."""
    return _build("controller", kind, params, context)


def build_estimator(kind: str, params: dict | None = None, context: BuildContext | None = None):
    """An estimator of ``kind`` (built-in name or import path) meeting the Estimator protocol."""
    return _build("estimator", kind, params, context)


def build_plant(kind: str, config=None, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0),
                params: dict | None = None):
    """A plant of ``kind`` (built-in name or import path) on ``config`` (a
    :class:`~twin.plant.base.TwinConfig`; None: the default one) at pitch ``theta0`` and heading
    ``alpha0`` (rad) and axle midpoint ``position`` (m), meeting :class:`twin.protocols.Plant`."""
    factory, plugin = resolve("plant", kind)
    if params is not None and not isinstance(params, dict):
        raise PluginError(f"plant {shown(kind)}: parameters must be a table of keyword arguments, got {shown(params)}")
    params = dict(params or {})
    if config is None:
        config = TwinConfig()
    if not plugin and params:
        raise PluginError(f"plant {shown(kind)}: unknown parameter{'s' * (len(params) > 1)} "
                          f"{', '.join(map(repr, params))}; allowed: none")
    try:
        if not plugin:
            plant = factory(config, theta0, alpha0, position)
        else:  # the same call, marked for the command that watches a plugin's calls
            _limits.mark(_ROLE_CODES["plant"], _limits.BUILDING)
            try:
                plant = factory(config, theta0, alpha0, position, **params)
            finally:
                _limits.unmark()
    except PluginError:
        raise
    except TwinError as exc:
        if not plugin:
            raise
        raise PluginError(f"plant {shown(kind)}: {exc}") from None
    except TypeError as exc:
        if not plugin:
            raise
        raise PluginError(f"plant {shown(kind)}: cannot be built as factory(config, theta0, alpha0, position"
                          f"{', **' + shown(params) if params else ''}) ({one_line(exc)}); allowed parameters: "
                          f"{', '.join(_parameters(factory)[4:]) or 'none'}") from None
    except _limits.PLUGIN_FAILURES as exc:  # the plugin's own failure, in one line
        raise PluginError(f"plant {shown(kind)}: building it raised {raised_text(exc)}"
                          + (f"; {MAY_NOT_END}" if ends_process(exc) else "")) from None
    check_plant(plant, kind=kind)
    return plant


def plant_motor(kind: str, config):
    """The motors a run's controllers and estimator are told of: ``config.motor`` for a plant
    ``kind`` whose class drives its wheels through them (:class:`twin.protocols.Plant`'s
    ``applies_motor``), else None (ideal torque sources). Imports a plugin kind's module."""
    return config.motor if getattr(resolve("plant", kind)[0], "applies_motor", False) else None


def check_plant(plant, sensors: bool = False, kind: str | None = None) -> None:
    """A one-line :class:`~twin.errors.PluginError` unless ``plant`` has the members of
    :class:`twin.protocols.Plant` (with ``sensors``, those the simulated IMU reads too)."""
    what = f"plant {shown(kind)}: {describe_object(plant)}" if kind else f"plant {describe_object(plant)}"
    missing = [f"{m}()" for m in _METHODS["plant"] if not callable(getattr(plant, m, None))]
    missing += [m for m in _PLANT_ATTRIBUTES + (_SENSOR_ATTRIBUTES if sensors else ()) if not hasattr(plant, m)]
    if missing:
        why = " (the simulated IMU reads them)" if sensors and set(missing) & set(_SENSOR_ATTRIBUTES) else ""
        raise PluginError(f"{what} has no {', '.join(missing)}{why}; a plant needs "
                          f"reset(theta0, alpha0, position), step(ul, ur), close(), control_rate, truth, status and "
                          f"end_reason, and kinematics, com_local and gravity with sensors (see "
                          f"twin.protocols.Plant)")
    rate = plant.control_rate
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= 100_000:
        raise PluginError(f"{what}: control_rate must be a frequency in (0, 100000] Hz, got "
                          f"{rate!r} (see twin.protocols.Plant)")


def build_estimator_for(kind: str, sensors, control_rate: float, motor, params, alpha0: float = 0.0,
                        compiled: bool | None = None, **options):
    """An estimator of ``kind`` (a built-in name or ``"package.module:attribute"``) for these
    sensors: :func:`build_estimator` with the context spelled out (this was
    ``estimation.build_estimator``; the estimator package no longer imports the registry).

    ``sensors`` a :class:`twin.sensors.SensorConfig` (None: only ``"ideal"``); ``control_rate`` Hz;
    ``motor`` the motors' specification (or None); ``params`` the robot model the estimator
    assumes; ``alpha0`` the initial heading (rad); ``compiled`` the EKF's implementation (see
    :class:`estimation.ekf.EKFEstimator`); ``options`` the estimator's own parameters.
    """
    if compiled is not None:
        options["compiled"] = compiled
    model = params if params is not None else _nominal()
    return build_estimator(kind, options, BuildContext(control_rate, model, motor, sensors, Targets(), alpha0))


def provenance(role: str, kind: str) -> dict | None:
    """For an import path: ``{"role", "kind", "module", "file", "sha256"}`` of the module
    that defines it (its source file's SHA-256); None for a built-in. The file is hashed
    once per process, when first asked: the code imported then is the code that runs. For
    ``export:DIR``: ``module`` None, ``file`` DIR's manifest, ``sha256`` over DIR's C sources
    and headers (which the user may have edited since the export)."""
    if is_export(kind):
        return _export_provenance(role, kind)
    if not is_import_path(kind):
        return None
    resolve(role, kind)
    module_name = kind.split(":", 1)[0]
    file, digest = _file_digest(module_name)
    return {"role": role, "kind": kind, "module": module_name, "file": file, "sha256": digest}


def _export_provenance(role: str, kind: str) -> dict:
    d = Path(kind[len(EXPORT_PREFIX):])
    h = hashlib.sha256()
    try:
        for f in sorted(p for p in d.iterdir() if p.suffix in (".c", ".h") and p.is_file()):
            h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
        digest = h.hexdigest()
    except OSError:
        digest = None
    return {"role": role, "kind": kind, "module": None, "file": str(d / "export.json"), "sha256": digest}


@functools.lru_cache(maxsize=None)
def _file_digest(module_name: str) -> tuple[str | None, str | None]:
    file = getattr(sys.modules[module_name], "__file__", None)
    if not file:
        return None, None
    try:
        return str(file), hashlib.sha256(Path(file).read_bytes()).hexdigest()
    except OSError:
        return str(file), None


def check_kinds(role: str, kinds, where: str) -> tuple[str, ...]:
    """``kinds`` as a tuple: at least one, each checked (:func:`check_kind`), none repeated;
    ``where`` names the option or key in the one-line error."""
    kinds = tuple(kinds)
    if not kinds:
        raise PluginError(f"{where} needs at least one {role} kind: {', '.join(_ROLES[role])} or "
                          "package.module:attribute")
    for kind in kinds:
        check_kind(role, kind)
    if len(set(kinds)) != len(kinds):
        raise PluginError(f"{where} {shown(list(kinds))}: a kind is repeated; list each once")
    return kinds


def parse_controllers(choice: str) -> tuple[str, ...]:
    """``"both"`` (it2 and t1), or a comma-separated list of kinds; each checked, none repeated."""
    if choice == "both":
        return ("it2", "t1")
    return check_kinds("controller", (s.strip() for s in str(choice).split(",") if s.strip()), "--controller")


__all__ = ["BuildContext", "CONTROLLERS", "ESTIMATORS", "EXPORT_PREFIX", "Kind", "exported_kind", "is_export", "build_controller", "build_estimator", "build_estimator_for",
           "look_beside",
           "check_kind", "check_kinds", "check_protocol", "is_import_path", "is_user_code", "label", "parse_controllers", "provenance", "resolve"]
