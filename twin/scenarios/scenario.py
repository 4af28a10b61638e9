"""A validated scenario and what it builds: the experiment, the twin, the sensors, the design.

Loading (:func:`load_scenario`) parses the TOML file (or a built-in by name), applies the
``--set KEY=VALUE`` overrides, validates everything against :mod:`twin.scenarios.schema`
and then builds every object the run needs once, so that an invalid scenario fails
before anything runs, with a one-line message naming the file, the key and what is
allowed.
"""
from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache, partial
from importlib import resources
from pathlib import Path

from twin.controllers import robot_settings
from twin.controllers.designs import adopt, balance_design
from twin.controllers.lmi import DEFAULT_RHO
from twin.errors import TwinError, shown
from twin.experiments import Experiment
from twin.inputs import MAX_TOML_BYTES, inside, read_text
from twin.limits import PluginLimits
from twin.params import NOMINAL, RobotParams
from twin.plant.base import START_TOLERANCE, TwinConfig, start_clearance, start_problem, touch_angle
from twin.plant.disturbances import Disturbances, Ground, Push
from twin.plant.urdf import Payload, body_box
from twin.registry import PLANTS, build_plant, look_beside, resolve
from twin.robots import Robot, builtin_names as builtin_robot_names, load_robot
from twin.scenarios.sensors import believed_config, problems, true_config
from twin.sim.spec import InitialState, Logging, Plugin, RunSpec, Sensing
from twin.scenarios.schema import (MAX_DEPTH, NAME_RULE, SCHEMA, ScenarioError, check_depth, key_text, lookup,
                                   name_problem, record, split_key, validate)
from twin.timing import steps_per_control

MIN_CLEARANCE_RAD = 0.3  # rad: the body box must clear the floor at least this far from upright
PAYLOAD_REACH = 0.1  # m: how far outside the body box a payload may sit (a bracket, a mast's foot)

BUILTIN_PACKAGE = "twin.scenarios.builtin"


def builtin_names() -> list[str]:
    """Names of the built-in scenarios, sorted."""
    files = resources.files(BUILTIN_PACKAGE).iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".toml"))


def builtin_scenarios() -> dict[str, str]:
    """Built-in name → its one-line description (read from the file; the tests validate every built-in)."""
    return {n: _read(n)[0].get("description", "") for n in builtin_names()}


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: ``data`` is the complete key tree (see :data:`~twin.scenarios.schema.SCHEMA`),
    ``source`` the file (or ``built-in NAME``) it came from, ``overrides`` the ``--set`` items applied."""

    data: dict
    source: str
    overrides: tuple[str, ...] = ()

    # what follows from the data is computed once (cached_property): ``data`` is validated and
    # not changed after the scenario is made (a changed scenario is a new one: --set, a sample);
    # the facts every run asks for are computed as it is made
    def __post_init__(self):
        for fact in ("name", "description", "duration", "seed", "controllers", "estimator", "plant_model",
                     "changed_keys", "sets_nothing", "robot"):
            getattr(self, fact)

    @cached_property
    def robot(self) -> Robot:
        """The robot (``robot``: a built-in's name or a robot file), whose figures are the nominal
        model, the drive, the sensors' defaults and the rates (:mod:`twin.robots`)."""
        try:
            return load_robot(self.data.get("robot", "paper"))
        except ScenarioError:
            raise
        except TwinError as exc:
            raise self._error(f"robot: {exc}") from None

    @cached_property
    def name(self) -> str:
        return self.data["name"]

    @cached_property
    def description(self) -> str:
        return self.data["description"]

    @cached_property
    def sets_nothing(self) -> bool:
        """True for a scenario whose every key is the default (an empty file): what it runs is
        then the schema's defaults, which a user may not expect."""
        return {**self.data, "name": "defaults"} == _defaults()

    @cached_property
    def duration(self) -> float:
        return self.data["duration"]

    @cached_property
    def seed(self) -> int:
        return self.data["seed"]

    @cached_property
    def video(self) -> dict:
        return self.data["video"]

    @cached_property
    def expect(self) -> dict:
        """The ``[expect]`` table: the bounds ``twin check`` holds the runs to (empty: none)."""
        return self.data["expect"]

    @cached_property
    def sweep(self) -> dict:
        """The ``[sweep]`` table: the uncertainty levels and what is drawn at each."""
        return self.data["sweep"]

    @cached_property
    def changed_keys(self) -> tuple[str, ...]:
        """The top-level tables and keys that ``--set`` items changed (besides the seed and
        duration), so that a description written for the file can be read with care."""
        keys = [split_key(o.partition("=")[0].strip())[0] for o in self.overrides]
        return tuple(dict.fromkeys(k for k in keys if k not in ("seed", "duration", "video", "sweep", "expect",
                                                              "name", "description", "limits")))

    @cached_property
    def controllers(self) -> tuple[str, ...]:
        """The controller kinds the scenario runs (``controller.kinds``)."""
        return tuple(self.data["controller"]["kinds"])

    @cached_property
    def estimator(self) -> str:
        """The estimator kind: ``"ideal"`` with ideal sensing, else ``sensors.estimator``."""
        s = self.data["sensors"]
        return "ideal" if s["sensing"] == "ideal" else s["estimator"]

    def record(self) -> dict:
        """The scenario as a run records it (metrics.json): complete, but keys added after
        0.1.0 left out while at their default (:func:`twin.scenarios.schema.record`)."""
        return record(self.data)

    # ---- what the scenario builds ------------------------------------------------------------
    def build_context(self, design=None):
        """The :class:`twin.registry.BuildContext` of this scenario's runs (their specification's,
        :meth:`twin.sim.spec.RunSpec.context`): nominal model, its motors, the sensors as the
        estimator believes them (:meth:`believed_sensor_config`), targets, heading, cascade
        options, and ``design`` (a zero-argument callable; default :meth:`design`, which solves
        the LMIs only when a controller asks)."""
        return self.run_specs((None,), design)[0].context()

    def build_controller(self, kind: str, context=None):
        """Controller ``kind`` with its ``[controller.params.KIND]``; a one-line error naming the key."""
        spec = self.run_specs((kind,), None if context is None else context.design)[0]
        if context is None:
            return spec.build_plugins(True, False, self.named(kind))["controller"]
        try:
            return spec.build_controller(context)
        except TwinError as exc:
            raise self.named(kind)("controller", exc) from None

    def build_estimator(self, context=None):
        """The scenario's estimator with ``sensors.estimator_params``; a one-line error naming the key."""
        spec = self.run_specs((None,), None if context is None else context.design)[0]
        if context is None:
            return spec.build_plugins(False, True, self.named(None))["estimator"]
        try:
            return spec.build_estimator(context)
        except TwinError as exc:
            raise self.named(None)("estimator", exc) from None

    def named(self, kind: str | None):
        """``named(role, error)`` for :meth:`twin.sim.spec.RunSpec.build_plugins`: the error of a
        plugin that cannot be built, as one line naming this scenario's key (a ScenarioError
        stands as it is)."""
        return partial(plugin_error, self.source, kind, self.data["controller"]["params"].get(kind) if kind else None,
                       None if self.estimator == "ideal" else self.data["sensors"]["estimator_params"])

    def run_spec(self, kind: str | None, context=None, build: bool = True):
        """The :class:`twin.sim.spec.RunSpec` of a run of this scenario with controller ``kind``
        (None: no controller; whoever steps the loop gives the torques, as a Gymnasium agent does).

        ``build``: the controller and the estimator are built here, once
        (:meth:`twin.sim.spec.RunSpec.built`), so a plugin that cannot be built is a one-line
        error naming the scenario's key before anything runs, and the spec carries the objects;
        False: the spec carries the kinds with their ``[controller.params.KIND]`` and
        ``sensors.estimator_params``, built by each run of it (:func:`twin.sim.simulate.simulate`).
        ``context``: a :class:`twin.registry.BuildContext` whose ``design`` the run uses (default
        :meth:`design`, solved when a controller asks)."""
        spec = self.run_specs((kind,), None if context is None else context.design)[0]
        return spec.built(self.named(kind)) if build else spec

    def run_specs(self, kinds, design=None) -> list:
        """The :class:`twin.sim.spec.RunSpec` of a run with each controller of ``kinds`` (None for
        no controller), their kinds not built: the same plant, sensors, seed and estimator;
        ``design``: the zero-argument callable the controllers take the LMI design from (default
        :meth:`design`)."""
        d = self.data
        i = d["initial"]
        params = d["controller"]["params"]
        estimator = Plugin(self.estimator, None if self.estimator == "ideal" else d["sensors"]["estimator_params"])
        shared = dict(estimator=estimator, plant=self.twin_config(), plant_model=self.plant_model,
                      plant_params=d["plant"]["params"], initial=InitialState(i["theta"], i["alpha"], i["x"], i["y"]),
                      targets=self.experiment().targets, duration=self.duration, seed=self.seed,
                      sensing=Sensing(self.sensor_config(), self.believed_sensor_config()),
                      design=self.design if design is None else design, options=self.cascade_options(),
                      logging=Logging(), name=self.name, description=self.description, limits=self.plugin_limits(),
                      model=self.model())
        plugins = [None if k is None else Plugin(k, params.get(k)) for k in kinds]
        return [RunSpec(controller=c, label=k or "", **shared) for k, c in zip(kinds, plugins)]

    def experiment(self):

        d = self.data
        return Experiment(d["name"], d["description"], theta0=d["initial"]["theta"],
                          p_d=d["targets"]["position"], alpha_d=d["targets"]["heading"], duration=d["duration"])

    @cached_property
    def plant_model(self) -> str:
        """``plant.model``: a plant kind of :mod:`twin.registry`: "bullet" (the PyBullet twin),
        "analytic" (equation (1)) or one's own "package.module:attribute"."""
        return self.data["plant"]["model"]

    def plant(self):
        """A new plant of ``plant.model`` on :meth:`twin_config` at the initial state (a
        :class:`twin.protocols.Plant`; :func:`twin.registry.build_plant`)."""
        i = self.data["initial"]
        return build_plant(self.plant_model, self.twin_config(), i["theta"], i["alpha"], (i["x"], i["y"]),
                           self.data["plant"]["params"])

    def model(self):
        """The model the controllers and the estimator assume: the robot's (:meth:`twin.robots.Robot.model`,
        with its drive's back-EMF damping where the twin drives the wheels through it), not the true plant."""
        return self._model

    @cached_property
    def _model(self):
        return self.robot.model(motors=self.twin_config().motor is not None)

    def true_params(self):

        return self.robot.params().perturbed(scale=self.data["plant"]["scale"])

    def twin_config(self):
        """The :class:`twin.plant.base.TwinConfig` of the true plant: the robot's figures with
        ``plant.scale`` applied, its drive (``plant.motor = "dc"``), rates, ground, disturbances and
        the tilt at which it is lost."""
        d, p = self.data, self.data["plant"]
        ground = Ground(**d["ground"])
        pushes = tuple(Push(tuple(q["force"]), q["start"], q["duration"], tuple(q["point"]), q["frame"])
                       for q in d["pushes"])
        payload = Payload(p["payload_mass"], tuple(p["payload_position"])) if p["payload_mass"] > 0 else None
        dist = Disturbances(pushes=pushes, payload=payload, com_offset=tuple(p["com_offset"]))
        # a built-in plant that does not drive its wheels through motors (Plant.applies_motor: the
        # analytic model's torque sources are ideal) has none, whatever plant.motor says; a plant of
        # one's own is not imported here (its code runs in a worker): it gets plant.motor's, and
        # registry.plant_motor says whether the controllers are told of them
        applies = p["model"] not in PLANTS or getattr(resolve("plant", p["model"])[0], "applies_motor", False)
        robot = self.robot
        return TwinConfig(params=self.true_params(), physics_rate=d["rates"]["physics"],
                          control_rate=d["rates"]["control"], ground=ground, disturbances=dist,
                          motor=robot.motor() if p["motor"] == "dc" and applies else None,
                          fall_angle=robot.fall_angle, body=robot.body_corners())

    def plugin_limits(self):
        """The scenario's ``[limits]`` as a :class:`twin.limits.PluginLimits`, or None if it sets none."""
        if not any(v is not None for v in self.data["limits"].values()):
            return None

        return PluginLimits(**self.data["limits"])

    def sensor_config(self):
        """The sensors the twin simulates (the true specification), or None for ideal sensing."""
        return true_config(self.data)

    def believed_sensor_config(self):
        """The sensors as the estimator believes them (``[sensors.believed]``; without it the
        true specification), or None for ideal sensing. The estimator's Q and R derive from it."""
        return believed_config(self.data)

    def design_options(self) -> dict:
        return dict(self.data["design"])

    def design(self):
        """The LMI balance design (on the nominal model), from the design store
        (:mod:`twin.controllers.designs`: solved once per process and set of options, and
        taken from the on-disk cache when it has it, when cvxpy is never imported)."""
        return solve_design(self.source, self.design_options(), self.model())

    def design_solver(self):
        """:meth:`design` as a zero-argument callable of this scenario's design options and robot alone."""
        return partial(solve_design, self.source, self.design_options(), self.model())

    def adopt_design(self, design) -> "Scenario":
        """Use ``design`` (solved elsewhere for these design options) instead of solving it
        again: a sweep's workers take the design the sweep solved once."""
        adopt(design, self.model(), **self.design_options())
        return self

    def cascade_options(self) -> dict:
        """The controllers' options (``fou``, ``type_reduction``, ``psi_error_limit``; the Mamdani
        ``universes`` and the LQR's input scale ``rho``, N·m, where they are not the paper's)."""
        c = self.data["controller"]
        options = {"fou": c["fou"], "type_reduction": c["type_reduction"], "psi_error_limit": c["psi_error_limit"]}
        universes = {k: v for k, v in c["universes"].items() if v != robot_settings.UNIVERSES[k][0]}
        if universes:
            options["universes"] = universes
        if self.data["design"]["rho"] != DEFAULT_RHO:
            options["rho"] = self.data["design"]["rho"]
        return options

    def check(self) -> "Scenario":
        """Build everything once: errors that involve several keys surface here, named."""
        d = self.data
        physics, control = d["rates"]["physics"], d["rates"]["control"]
        if d["duration"] < 1.0 / control - 1e-12:
            raise self._error(f"duration: {d['duration']:g} s is shorter than one control period; allowed: at least "
                              f"{1.0 / control:g} s (1 / rates.control) up to 3600 s")
        try:
            steps_per_control(1.0 / physics, 1.0 / control)
        except TwinError:
            raise self._error(f"rates.control: {control:g} Hz does not divide rates.physics = {physics:g} Hz; allowed: "
                              f"a control rate whose period is a whole number of physics steps (e.g. "
                              f"{', '.join(f'{physics / k:g}' for k in (10, 5, 4, 2, 1))} Hz)") from None
        for group in ("pushes", "faults"):
            for i, item in enumerate(d[group]):
                if item["start"] >= d["duration"]:
                    raise self._error(f"{group}[{i}].start: {item['start']:g} s is not before the end of the run "
                                      f"(duration = {d['duration']:g} s); allowed: [0, {d['duration']:g}) s")

        def sensors():
            problem = problems(d, self.true_params(), self.robot.body_corners())
            if problem:
                raise self._error(problem)
            config = self.sensor_config()
            self.believed_sensor_config()
            return None if config is None else config.steps(control)

        self._check_analytic()
        for where, build in (("plant", self.true_params), ("twin", self.twin_config), ("sensors", sensors)):
            try:
                build()
            except ScenarioError:
                raise
            except TwinError as exc:
                raise self._error(f"{where}: {exc}") from None

        config = self.twin_config()  # validated just above
        limit = min(touch_angle(config.params, config.body), config.fall_angle) - 0.01
        theta0 = d["initial"]["theta"]
        if abs(theta0) >= limit:
            self._check_body_clears_floor(config.params, config.body)  # the body's size is to blame, not the tilt
            raise self._error(f"initial.theta: {theta0:g} rad does not start on the wheels: this robot's body touches "
                              f"the floor (or passes the fall limit) at {limit + 0.01:.2f} rad; allowed: |θ0| < "
                              f"{limit:.2f} rad")
        self._check_payload_on_body(config)
        self._check_start(config)
        self.design()
        return self

    def _check_payload_on_body(self, config) -> None:
        """A payload is a mass fixed to the body: one far outside the body box (a 20 kg mass
        half a metre away, on nothing) is a typo or a unit slip, refused naming the key."""
        payload = config.disturbances.payload
        if payload is None:
            return
        lo, hi = body_box(config.params, config.body)
        pos = payload.position
        gap = max(max(lo[i] - pos[i], pos[i] - hi[i], 0.0) for i in range(3))
        if gap <= PAYLOAD_REACH:
            return
        allowed = ", ".join(f"{axis} {lo[i] - PAYLOAD_REACH:.3g} to {hi[i] + PAYLOAD_REACH:.3g}"
                            for i, axis in enumerate("xyz"))
        raise self._error(f"plant.payload_position: [{', '.join(f'{c:g}' for c in pos)}] m is {gap:.3g} m outside "
                          f"the body box; allowed: within {PAYLOAD_REACH:g} m of it ({allowed} m, body frame from "
                          f"the axle, for this plant)")

    def _check_body_clears_floor(self, params, body=None) -> None:
        """Where the initial tilt does not start on the wheels and the body box (its height follows
        l, twin.plant.urdf.body_height) clears the floor by less than MIN_CLEARANCE_RAD of tilt, the
        body's size is to blame: the error names plant.scale.l with the range that clears it (it
        blamed initial.theta, issue 31)."""
        touch = touch_angle(params, body)
        if touch >= MIN_CLEARANCE_RAD:
            return
        if body is not None:  # the robot's own box: its file is to blame
            raise self._error(f"robot: the body's box (the robot file's body.size and body.box_bottom) reaches the "
                              f"floor at {touch:.2f} rad of tilt; allowed: a box that clears the floor to "
                              f"{MIN_CLEARANCE_RAD:g} rad")
        ok = [f / 100.0 for f in range(20, 501)
              if touch_angle(params.replace(l=self.robot.params().l * f / 100.0)) >= MIN_CLEARANCE_RAD]
        allowed = f"from {ok[0]:g} to {ok[-1]:g}" if ok else "none with this robot's other parameters"
        raise self._error(f"plant.scale.l: the body's centre of mass at l = {params.l:.4g} m makes a body box "
                          f"(twin/plant/urdf.py) that reaches the floor at {touch:.2f} rad of tilt; allowed: a body "
                          f"that clears the floor to {MIN_CLEARANCE_RAD:g} rad, plant.scale.l {allowed}")

    def _check_analytic(self) -> None:
        """With ``plant.model = "analytic"``, what only the PyBullet twin models is refused, naming the key."""
        d = self.data
        if d["plant"]["model"] != "analytic":
            return

        keys = SCHEMA["plant"].keys
        used = ["plant.payload_mass"] * (d["plant"]["payload_mass"] != keys["payload_mass"].default)
        used += ["plant.com_offset"] * (tuple(d["plant"]["com_offset"]) != tuple(keys["com_offset"].default))
        used += [f"ground.{k}" for k, key in SCHEMA["ground"].keys.items() if d["ground"][k] != key.default]
        used += ["pushes"] * bool(d["pushes"])
        if used:
            raise self._error(f"{used[0]}: the analytic plant (plant.model = \"analytic\", equation (1)) rolls without "
                              f"slip on a level floor and has no pushes, payload or centre-of-mass offset; allowed: "
                              f"{used[0]} at its default with it, or plant.model = \"bullet\"")

    def _check_start(self, config) -> None:
        """Every part of the robot starts above the floor (:func:`twin.plant.bullet.start_problem`):
        a payload below it, or a body pitched into a slope, is refused, naming the key."""
        d = self.data
        i = d["initial"]
        args = (config.params, config.ground, i["theta"], i["alpha"], (i["x"], i["y"]))
        payload = config.disturbances.payload
        problem = start_problem(*args, payload, config.body)
        if problem is None:
            return
        clearance = start_clearance(*args, payload, config.body)
        if clearance.get("payload", 0.0) < -START_TOLERANCE:
            # the clearance is linear in the payload's z: the lowest z that starts above the floor
            x, y, _ = payload.position
            c0, c1 = (start_clearance(*args, replace(payload, position=(x, y, z)), config.body)["payload"]
                      for z in (0.0, 1.0))
            z_min = -c0 / (c1 - c0)
            hint = (f"a payload_position whose z is at least {z_min:.3g} m here (x = {x:g}, y = {y:g} m)"
                    if z_min <= 0.5 else "a payload_position above the floor")
            raise self._error(f"plant.payload_position: {problem}; allowed: {hint}")
        raise self._error(f"initial.theta: {problem}; allowed: a smaller pitch towards the slope, or a gentler "
                          f"ground.slope")

    def _error(self, message: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: {message}")


@lru_cache(maxsize=1)
def _defaults() -> dict:
    """The schema's defaults, as an empty scenario file validates (compare only: not to be changed)."""
    return validate({"name": "defaults"})


def solve_design(source: str, options: dict, params: RobotParams = NOMINAL):
    """The LMI balance design of a scenario's ``[design]`` ``options`` (from ``source``) on the
    robot's model ``params``, from the design store; a one-line error naming the scenario's key."""
    try:
        return balance_design(params, **options)
    except TwinError as exc:
        msg = str(exc)
        for flag, name in (("--epsilon", "design.epsilon"), ("--rho", "design.rho"),
                           ("--decay-rate", "design.decay_rate"), ("--max-gain", "design.max_gain"),
                           ("--damping", "design.damping"), ("--uncertain", "design.uncertain")):
            msg = msg.replace(flag, name)
        raise ScenarioError(f"{source}: design: {msg}") from None


def plugin_error(source: str, kind: str | None, controller_params, estimator_params, role: str,
                 exc: TwinError) -> TwinError:
    """A plugin of a scenario's run that cannot be built, as one line naming the scenario's key
    (``controller.params.KIND`` or ``controller``, ``sensors.estimator_params`` or
    ``sensors.estimator``); a ScenarioError stands as it is."""
    if isinstance(exc, ScenarioError):
        return exc
    if role == "controller":
        where = f"controller.params.{kind}" if controller_params else "controller"
    else:
        where = "sensors.estimator_params" if estimator_params else "sensors.estimator"
    return ScenarioError(f"{source}: {where}: {exc}")


def parse_override(item: str) -> tuple[str, object]:
    """``KEY=VALUE`` → (dotted key, value): VALUE is read as TOML (numbers, true/false, [lists],
    {inline tables}, "strings"), and as a bare string if it is not TOML."""
    key, sep, text = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ScenarioError(f"--set {shown(item)}: expected KEY=VALUE with a dotted key, e.g. --set plant.scale.m_b=1.2")
    lookup(key)
    try:
        value = tomllib.loads(f"v = {text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = text.strip()
    except (RecursionError, ValueError) as exc:  # TOML, but more than the reader can take
        raise ScenarioError(f"--set {key_text(key)}: the value cannot be read: {_unreadable(exc)}") from None
    check_depth(value, f"--set {key_text(key)}: ")
    return key, value


def _unreadable(exc: Exception) -> str:
    """Why tomllib could not read valid-looking TOML, in one line."""
    if isinstance(exc, RecursionError):
        return f"nested too deeply for the TOML reader; allowed: at most {MAX_DEPTH} levels of tables and lists"
    if "digits" in str(exc):
        return "an integer with more than 4300 digits; allowed: integers within the key's range"
    return " ".join(str(exc).split())[:200]


def _item(override: str) -> str:
    """A ``--set`` item for a message: as given if it is short and printable, else quoted,
    escaped and shortened (the message must stay one line)."""
    text = str(override)
    return text if text.isprintable() and len(text) <= 80 else shown(text)


def apply_overrides(raw: dict, overrides) -> dict:
    raw = copy.deepcopy(raw)
    for item in overrides:
        key, value = parse_override(item)
        node = raw
        parts = split_key(key)
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ScenarioError(f"--set {key_text(key)}: {shown(part)} is not a table in the scenario")
            node = child
        node[parts[-1]] = value
    return raw


MAX_FILE_BYTES = MAX_TOML_BYTES  # a scenario file (the built-ins are about 2 kB): 1 MiB


def _read(name_or_path: str, within: Path | None = None) -> tuple[dict, str, str]:
    """(parsed TOML, source for messages, default name). A file is read only if it is a regular
    file of at most :data:`MAX_FILE_BYTES` (a FIFO would block, ``/dev/zero`` never ends) and,
    with ``within``, only if it lies in that directory (a sensor log's scenario and its bases:
    the log's own files, :func:`twin.inputs.inside`)."""
    if "\x00" in name_or_path:  # no file name holds one (the OS refuses it): one line, not a ValueError
        raise ScenarioError(f"{shown(name_or_path, 300)}: a name with a null character; allowed: a built-in "
                            f"scenario's name or a .toml file's path")
    path = Path(name_or_path)
    if name_or_path in builtin_names():
        text = resources.files(BUILTIN_PACKAGE).joinpath(f"{name_or_path}.toml").read_text(encoding="utf-8")
        source, stem = f"built-in scenario {name_or_path}", name_or_path
    elif path.suffix == ".toml" or path.exists():
        shown_path = str(path) if str(path).isprintable() else shown(str(path))  # a message stays one line
        try:
            if within is not None:
                inside(path, within, "scenario file")
            text = read_text(path, MAX_FILE_BYTES, "scenario file")
        except FileNotFoundError:
            raise ScenarioError(f"{shown_path}: no such scenario file") from None
        except TwinError as exc:  # not a regular file, too large, not UTF-8, outside ``within``: already one line
            raise ScenarioError(str(exc) if shown_path == str(path) else str(exc).replace(str(path), shown_path, 1)) \
                from None
        source, stem = shown_path, path.stem
        if within is None:  # a sensor log's scenario is data: its folder is no place to import code from
            look_beside(path.parent)  # the plugins a scenario file names may lie beside it
    else:
        raise ScenarioError(f"{name_or_path!r} is neither a built-in scenario nor a .toml file; built-ins: "
                            f"{', '.join(builtin_names())} (see 'twin scenarios')")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML ({' '.join(str(exc).split())})") from None
    except (RecursionError, ValueError) as exc:
        raise ScenarioError(f"{source}: cannot be read: {_unreadable(exc)}") from None
    check_depth(raw, f"{source}: ")
    return raw, source, stem


BASE_KEY = "base"   # a scenario file's first key: the built-in or file it starts from
MAX_BASES = 8       # a chain of bases longer than this is refused (it is a mistake, or a cycle)
REPLACED = ("expect",)  # tables a derived file replaces whole: bounds are judged as a set


def merged(base: dict, child: dict) -> dict:
    """``child`` over ``base``: tables merge key by key, at every depth; every other value
    (numbers, strings, arrays such as ``pushes`` and ``faults``) and the tables of
    :data:`REPLACED` are taken from ``child`` whole where it gives them."""
    out = copy.deepcopy(base)
    for key, value in child.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and key not in REPLACED:
            out[key] = merged(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _with_bases(raw: dict, source: str, path: Path | None, chain: tuple = (), within: Path | None = None) -> dict:
    """``raw`` over the scenario its ``base`` names (a built-in's name, or a .toml file
    relative to ``path``'s directory), itself resolved first; ``name`` is never inherited (a
    derived scenario is named by its own file or its own ``name``). ``chain``: the sources
    that lead here (for the depth limit and the cycle); ``within``: the directory every base
    file must lie in (:func:`_read`)."""
    if BASE_KEY not in raw:
        return raw
    chain = (*chain, source)
    base = raw[BASE_KEY]
    if not isinstance(base, str) or not base:
        raise ScenarioError(f"{source}: base: {shown(base)} is not a name; allowed: a built-in scenario's name "
                            f"({', '.join(builtin_names())}) or a .toml file, relative to this file")
    if "\x00" in base:  # no file name holds one: one line, not the OS's ValueError
        raise ScenarioError(f"{source}: base: {shown(base)} holds a null character; allowed: a built-in scenario's "
                            f"name or a .toml file, relative to this file")
    if len(chain) > MAX_BASES:
        raise ScenarioError(f"{chain[0]}: base: more than {MAX_BASES} scenarios deep ({' -> '.join(chain)}); "
                            f"allowed: a chain of at most {MAX_BASES}")
    builtin = base in builtin_names()
    if not builtin and path is None:
        raise ScenarioError(f"{source}: base: {shown(base)} is not a built-in scenario; allowed: "
                            f"{', '.join(builtin_names())}")
    target = base if builtin else str(path.parent / base)
    if not builtin and Path(target).suffix != ".toml":
        raise ScenarioError(f"{source}: base: {shown(base)} is neither a built-in scenario nor a .toml file; "
                            f"allowed: {', '.join(builtin_names())}, or a .toml file relative to this file")
    try:
        parent, parent_source, _ = _read(target, within)
    except ScenarioError as exc:
        raise ScenarioError(f"{source}: base: {exc}") from None
    if parent_source in chain:
        raise ScenarioError(f"{chain[0]}: base: the scenarios name each other in a cycle "
                            f"({' -> '.join(chain + (parent_source,))})")
    parent = _with_bases(parent, parent_source, None if builtin else Path(target), chain, within)
    return merged({k: v for k, v in parent.items() if k != "name"}, {k: v for k, v in raw.items() if k != BASE_KEY})


# scenario keys a robot sets, with what it sets them to (those the scenario gives stay its own)
ROBOT_SET = {
    ("rates", "control"): lambda r: r.control_rate,
    ("sensors", "imu"): lambda r: r.values["imu"]["part"],
    ("sensors", "imu_position"): lambda r: r.imu().position,
    ("sensors", "imu_orientation"): lambda r: r.values["imu"]["orientation"],
    ("sensors", "imu_rate"): lambda r: r.imu().rate,
    ("sensors", "imu_latency"): lambda r: r.imu().latency,
    ("sensors", "encoder_counts"): lambda r: r.encoders().counts_per_rev,
    ("sensors", "encoder_latency"): lambda r: r.encoders().latency,
    # the IMU's own constants, where the robot file knows them
    **{("sensors", triad, key): (lambda r, name=f"{triad}_{key}": r.values["imu"][name])
       for triad in ("gyro", "accel") for key in ("bias", "scale")},
    # the controllers' settings the robot implies (twin.controllers.robot_settings)
    ("design", "rho"): lambda r: robot_settings.design_settings(r)["rho"],
    ("design", "decay_rate"): lambda r: robot_settings.design_settings(r)["decay_rate"],
    **{("controller", "universes", name): (lambda r, name=name: robot_settings.universes(r)[name])
       for name in robot_settings.UNIVERSES},
}


def _take_robot(data: dict, raw: dict, path: Path | None, where: str, within: Path | None = None) -> None:
    """The scenario's ``robot`` loaded (a file relative to the scenario file, or for a built-in
    scenario to ``within``, as an absolute path in ``data``), and each key of :data:`ROBOT_SET` the
    scenario does not give set to the robot's figure where it differs from what the key's absence
    means (the paper's robot changes nothing). ``within`` (a sensor log's directory): a robot
    file must lie in it (the log carries its robot as robot.toml)."""
    name = data["robot"]
    if name not in builtin_robot_names() and not Path(name).is_absolute():
        base = path.parent if path is not None else within
        if base is not None and (base / name).is_file():
            data["robot"] = name = str((base / name).resolve())
    try:
        if within is not None and name not in builtin_robot_names():
            inside(Path(name), within, "robot file")
        robot = load_robot(name)
    except TwinError as exc:
        raise ScenarioError(f"{where}: robot: {exc}") from None
    paper = load_robot("paper")
    for keys, figure in ROBOT_SET.items():
        given, into = raw, data
        for key in keys[:-1]:
            given = given.get(key) if isinstance(given, dict) else None
            into = into[key]
        if not (isinstance(given, dict) and keys[-1] in given) and figure(robot) != figure(paper):
            into[keys[-1]] = figure(robot)


def load_scenario(name_or_path: str, overrides=(), *, within=None) -> Scenario:
    """A built-in scenario by name, or a scenario file, with ``--set`` ``overrides`` applied;
    validated and checked (:meth:`Scenario.check`). A file may start from another scenario
    with ``base = "NAME"`` (a built-in) or ``base = "FILE.toml"`` (relative to the file): its
    keys are laid over that scenario's (see :func:`merged`). ``within``: a directory the file
    and every base file must lie in (a sensor log's; None: anywhere)."""
    within = None if within is None else Path(within)
    raw, source, stem = _read(str(name_or_path), within)
    raw = _with_bases(raw, source, None if source.startswith("built-in") else Path(str(name_or_path)),
                      within=within)
    overrides = tuple(overrides)
    # each item as the user gave it, on one line and shortened: the message must stay one line
    where = source + (f" with --set {' '.join(_item(o) for o in overrides)}" if overrides else "")
    try:
        raw = apply_overrides(raw, overrides)
        data = validate(raw)
    except ScenarioError as exc:
        msg = str(exc)
        raise ScenarioError(msg if msg.startswith("--set") else f"{where}: {msg}") from None
    if not data["name"]:
        problem = name_problem(stem)
        if problem:
            raise ScenarioError(f"{where}: name: absent, and the file's name {shown(stem)} {problem}, so it cannot "
                                f"be the scenario's name; allowed: a file name or a name = \"...\" in the file of "
                                f"{NAME_RULE}")
        data["name"] = stem
    latency_given = [("latency" in f) for f in raw.get("faults", [])] if isinstance(raw.get("faults"), list) else []
    relevant = {"dropout": {"kind", "sensor", "start", "duration"}, "stuck": {"kind", "sensor", "start", "duration"},
                "spikes": {"kind", "sensor", "start", "duration", "rate", "magnitude"},
                "latency": {"kind", "sensor", "start", "latency"}}
    for i, f in enumerate(raw.get("faults", [])):
        extra = sorted(set(f) - relevant[data["faults"][i]["kind"]])
        if extra:
            raise ScenarioError(f"{where}: faults[{i}].{extra[0]}: a {data['faults'][i]['kind']} fault has no "
                                f"{extra[0]!r}; allowed: {', '.join(sorted(relevant[data['faults'][i]['kind']]))}")
    _take_robot(data, raw, None if source.startswith("built-in") else Path(str(name_or_path)), where, within)
    scenario = Scenario(data, where, overrides)
    for i, f in enumerate(data["faults"]):
        if f["kind"] == "latency" and not latency_given[i]:
            raise ScenarioError(f"{where}: faults[{i}].latency: missing; a latency fault needs the new latency in s")
    return scenario.check()


__all__ = ["Scenario", "ScenarioError", "builtin_names", "builtin_scenarios", "load_scenario", "parse_override"]
