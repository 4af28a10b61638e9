"""The scenario file's schema: every key, its type, unit, default and allowed range.

A scenario is a TOML file (see ``twin/scenarios/builtin/`` and docs/howto/scenarios.md). :func:`validate` checks a parsed file against :data:`SCHEMA` and returns it
complete, with every default filled in; the first problem found is raised as a
:class:`ScenarioError` naming the file, the dotted key and what is allowed. Checks that
involve several keys (a control rate that does not divide the physics rate, ...) are in
:mod:`twin.scenarios.scenario`.
"""
from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from typing import Any

from twin.controllers.cascade import DEFAULT_PSI_ERROR_LIMIT
from twin.controllers.lmi import (DEFAULT_ALL_VERTICES, DEFAULT_DAMPING, DEFAULT_DECAY_RATE, DEFAULT_EPSILON, DEFAULT_RHO,
                                  DEFAULT_UNCERTAIN, MIN_EPSILON)
from twin.controllers.lmi_regions import UNCERTAIN_PARAMETERS
from twin.controllers.mamdani import DEFAULT_FOU, P_E_RANGE
from twin.controllers.robot_settings import UNIVERSES
from twin.fuzzy.mamdani import TYPE_REDUCERS
from twin.errors import TwinError, shown
from twin.params import PARAMETER_DOCS
from twin.registry import check_kind
from twin.sensors.specs import IMU_PRESETS
from twin.sensors.types import extra_types

REQUIRED = object()


class ScenarioError(TwinError):
    """An invalid scenario file or override (the message names the file and the key)."""


@dataclass(frozen=True)
class Key:
    """One key: ``kind`` is float, int, bool, str, vec3, table (``keys``), tables (a list of
    tables, ``keys``), map (str → float, names from ``choices``), floats (a non-empty list of
    numbers), range (two numbers [low, high], low ≤ high) or names (a list from ``choices``)."""

    kind: str
    default: Any = REQUIRED
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    unit: str = ""
    choices: tuple = ()
    doc: str = ""
    keys: dict = field(default_factory=dict)
    nullable: bool = False  # absent means None
    role: str = ""  # kind, kinds: "controller" or "estimator" (checked by twin.registry)
    # Keys added after 0.1.0 are left out of a run's record (metrics.json) while at their
    # default, so that the record of a run that does not use them stays byte-identical.
    recorded_at_default: bool = True
    recorded: bool = True  # False: never part of a run's record (what checks the run, not what it ran)
    hi_open: bool = False
    check: Any = field(default=None, compare=False)  # str, int: check(value, path) raises on what the kind allows but the key does not


NAME_MAX = 64  # characters of a scenario name
NAME_RULE = (f"1 to {NAME_MAX} characters from A-Z a-z 0-9 _ - . (ASCII letters and digits, underscore, hyphen, "
             f"full stop), the first a letter, a digit or _")
DESCRIPTION_MAX = 240  # characters of a description (the figure's title wraps it at 140)
MAX_DEPTH = 32  # levels of nested tables and lists in a scenario (a plugin's matrix parameter needs 5)
_NAME = re.compile(rf"[A-Za-z0-9_][A-Za-z0-9_.-]{{0,{NAME_MAX - 1}}}")


def name_problem(name: str) -> str | None:
    """What breaks the scenario-name rule (:data:`NAME_RULE`) in ``name``, or None. The name is
    a directory's name (``runs/NAME``, ``runs/sweep-NAME``): no path separator, no ``.`` or
    ``..``, nothing a shell or another file system reads differently."""
    if _NAME.fullmatch(name):
        return None
    if not name:
        return "is empty"
    if len(name) > NAME_MAX:
        return f"has {len(name)} characters"
    for c in name:
        if not (c.isascii() and (c.isalnum() or c in "_-.")):
            what = ("a path separator" if c in "/\\" else "a control character" if not c.isprintable()
                    else "a space" if c == " " else "not allowed")
            return f"has {repr(c) if c.isprintable() else f'U+{ord(c):04X}'} ({what})"
    return f"starts with {name[0]!r}"


def _check_name(v: str, path: str) -> None:
    if v:  # "": the file's name (checked where it is taken, twin.scenarios.scenario)
        problem = name_problem(v)
        if problem:
            raise ScenarioError(f"{path}: {shown(v)} {problem}; allowed: {NAME_RULE} (the name is the output "
                                f"folder's: runs/NAME)")


def _check_even(v: int, path: str) -> None:
    # H.264 in the yuv420p every browser plays halves the colour planes: the frame's sides must be even
    if v % 2:
        raise ScenarioError(f"{path}: {v} is odd; allowed: an even number of pixels (H.264's yuv420p halves the "
                            f"colour planes), e.g. {v - 1} or {v + 1}")


def _check_description(v: str, path: str) -> None:
    bad = next((c for c in v if not c.isprintable()), None)
    if bad is not None:
        what = "a line break" if bad in "\n\r" else f"the control character U+{ord(bad):04X}"
        raise ScenarioError(f"{path}: {shown(v)} has {what}; allowed: one line of at most {DESCRIPTION_MAX} "
                            f"printable characters")
    if len(v) > DESCRIPTION_MAX:
        raise ScenarioError(f"{path}: {shown(v)} has {len(v)} characters; allowed: one line of at most "
                            f"{DESCRIPTION_MAX} printable characters")


def check_depth(value, prefix: str = "") -> None:
    """A one-line error (``prefix`` first) if ``value`` (parsed TOML) nests tables and lists
    deeper than :data:`MAX_DEPTH`: checked before anything recurses into it (a copy, a
    message's repr), which Python's recursion limit would break at a depth of about 1000."""
    stack = [(value, 0, "")]
    while stack:
        v, depth, path = stack.pop()
        if depth > MAX_DEPTH:
            raise ScenarioError(f"{prefix}{path or 'the value'}: nested more than {MAX_DEPTH} levels deep; allowed: "
                                f"at most {MAX_DEPTH} levels of tables and lists")
        # (only the containers below are visited: a list of a million numbers costs no paths)
        if isinstance(v, dict):
            stack.extend((c, depth + 1, f"{path}.{key_text(k)}" if path else key_text(k)) for k, c in v.items()
                         if isinstance(c, (dict, list, tuple)))
        elif isinstance(v, (list, tuple)):
            stack.extend((c, depth + 1, f"{path}[{i}]") for i, c in enumerate(v) if isinstance(c, (dict, list, tuple)))


def key_text(name) -> str:
    """A table key as a message shows it: bare if it is a plain word, else quoted and shortened."""
    return name if isinstance(name, str) and re.fullmatch(r"[A-Za-z0-9_.:-]{1,64}", name) else shown(name, 40)


def _f(default=REQUIRED, lo=-math.inf, hi=math.inf, unit="", doc="", lo_open=False, nullable=False):
    return Key("float", default, lo, hi, lo_open, unit, doc=doc, nullable=nullable)


PUSH = {
    "force": Key("vec3", REQUIRED, -1e4, 1e4, unit="N", doc="force (x forward, y left, z up in the frame)"),
    "start": _f(REQUIRED, 0.0, 3600.0, "s"),
    "duration": _f(REQUIRED, 0.0, 10.0, "s", lo_open=True),
    "point": Key("vec3", (0.0, 0.0, 0.1), -1.0, 1.0, unit="m", doc="point of application, body frame"),
    "frame": Key("str", "heading", choices=("heading", "world")),
}

FAULT = {
    "kind": Key("str", REQUIRED, choices=("dropout", "stuck", "spikes", "latency")),
    "sensor": Key("str", REQUIRED, choices=("gyro", "accel", "imu", "encoders", "all")),
    "start": _f(0.0, 0.0, 3600.0, "s", doc="start of the window (dropout, stuck, spikes) or of the new latency"),
    "duration": _f(math.inf, 0.0, math.inf, "s", lo_open=True, doc="length of the window (inf: to the end)"),
    "rate": _f(2.0, 0.0, 1e4, "1/s", lo_open=True, doc="spikes: expected outliers per second"),
    "magnitude": _f(1.0, 0.0, 1e6, "sensor unit", lo_open=True, doc="spikes: offset on every axis"),
    "latency": _f(0.0, 0.0, 1.0, "s", doc="latency: the new latency"),
}

def _triad(unit: str, absent: str, known: bool = True) -> Key:
    """[sensors.gyro] / [sensors.accel] (and under [sensors.believed]): overrides of the preset's
    figures, in SI units; each absent key is ``absent``'s figure. ``known``: with the device's own
    constants (``bias``, ``scale``: the true sensor's, where known; a robot file's sets them)."""
    def new(kind, lo, hi, u, doc, lo_open=False):
        return Key(kind, None, lo, hi, lo_open, u, doc=f"{doc}; absent: {absent}", nullable=True,
                   recorded_at_default=False)

    constants = {} if not known else {
        "bias": Key("vec3", None, -1e3, 1e3, unit=unit, nullable=True, recorded_at_default=False,
                    doc="the device's own constant bias, x y z, where known: every run has it instead of a "
                        "drawn turn-on bias; absent: drawn per run"),
        "scale": Key("vec3", None, -0.5, 0.5, unit="1", nullable=True, recorded_at_default=False,
                     doc="the device's own scale-factor errors, x y z, where known (instead of draws); absent: "
                         "drawn per run"),
    }
    return Key("table", recorded_at_default=False, keys={
        "noise_density": new("float", 0.0, 1e3, f"{unit}/√Hz",
                             "white noise density (per-sample σ = density·√rate)"),
        "bias_random_walk": new("float", 0.0, 1e3, f"{unit}/√s", "bias random walk K (the bias moves K·√Δt per "
                                "sample; with a correlation time, drives the Gauss–Markov bias)"),
        "bias_correlation_time": new("float", 0.0, 1e7, "s",
                                     "the bias is first-order Gauss–Markov with this time constant (steady σ = "
                                     "K·√(τ/2)) instead of a random walk (as in every preset)", lo_open=True),
        "turn_on_bias": new("float", 0.0, 1e3, unit, "σ of the constant bias drawn per run, per axis"),
        "scale_factor_error": new("float", 0.0, 0.5, "1", "σ of the per-axis sensitivity error"),
        "full_scale": new("float", 0.0, 1e6, unit, "range ±full_scale (at least 5 × the per-sample white noise)",
                          lo_open=True),
        "bits": new("int", 2, 32, "bits", "ADC resolution (LSB = full_scale / 2^(bits−1))"),
        **constants,
    })


def _sensor_type(t) -> Key:
    """[sensors.<type>] of a sensor type beyond the IMU and encoders (:data:`twin.sensors.types.
    SENSOR_TYPES`: the motor current): its keys from the type's table, each absent by default (the
    type's own default); the sensor is on when ``enabled = true``, or when any other key is given
    without ``enabled = false``. Left out of a run's record while absent."""
    keys = {"enabled": Key("bool", None, nullable=True, recorded_at_default=False,
                           doc=f"simulate the {t.name} sensor ({t.doc}); absent: on if any other "
                               f"[sensors.{t.name}] key is given")}
    for name, k in t.keys.items():
        unit = "" if k.unit == "1" else k.unit
        default = "the control rate" if k.default is None else f"{k.default:.6g}{' ' + unit if unit else ''}"
        keys[name] = Key(k.kind, None, k.lo, k.hi, k.lo_open, k.unit, doc=f"{k.doc}; absent: {default}",
                         nullable=True, recorded_at_default=False)
    return Key("table", recorded_at_default=False, doc=t.doc, keys=keys)


def _believed_triad(unit: str) -> Key:
    return _triad(unit, "as believed.imu's preset, or (without it) as the true sensor", known=False)


SCHEMA: dict[str, Key] = {
    "name": Key("str", "", check=_check_name,
                doc=f"short name, also the output folder's (runs/NAME): {NAME_RULE}; no path separators, "
                    f"no '.' or '..' (default: the file's name, which must then follow the same rule)"),
    "description": Key("str", "", check=_check_description,
                       doc=f"one line of at most {DESCRIPTION_MAX} printable characters: what the scenario shows"),
    "duration": _f(15.0, 0.0, 3600.0, "s", lo_open=True, doc="simulated time"),
    "seed": Key("int", 0, 0, 2 ** 63 - 1, doc="seed of the sensor noise, faults and sampled disturbances"),
    "reference": Key("bool", False, recorded_at_default=False,
                     doc="true: a reference run, not a test of an estimator: an estimator plugin that reads the "
                         "ground truth (reads_truth = True) is then allowed under twin check, which refuses it "
                         "otherwise"),
    "robot": Key("str", "paper", recorded_at_default=False,
                 doc="the robot: a built-in's name ('twin robots') or a robot file (.toml, relative to the scenario "
                     "file); the keys below that it sets (rates.control, the IMU's and the encoders') take its "
                     "figures unless the scenario gives them, and plant.scale's factors are of its figures"),
    "initial": Key("table", keys={
        "theta": _f(0.48, -0.99, 0.99, "rad", doc="body pitch (inside the fall limit of 1 rad)"),
        "alpha": _f(0.0, -math.pi, math.pi, "rad", doc="heading"),
        "x": _f(0.0, -1e4, 1e4, "m"),
        "y": _f(0.0, -1e4, 1e4, "m"),
    }),
    "targets": Key("table", keys={
        "position": _f(None, -P_E_RANGE, P_E_RANGE, "m", nullable=True,
                       doc="travel target p_d (Table I's position-error range); absent: no position loop"),
        "heading": _f(None, -math.pi, math.pi, "rad", nullable=True,
                      doc="heading target α_d; absent: no direction loop"),
    }),
    "controller": Key("table", keys={
        "kinds": Key("kinds", ("it2", "t1"), role="controller", recorded_at_default=False,
                     doc="the controllers run on identical conditions: built-in names (it2, t1, lqr) or "
                         "import paths 'package.module:attribute' (runs that module's code)"),
        "params": Key("params", {}, recorded_at_default=False, role="controller",
                      doc="[controller.params.KIND]: keyword arguments for building controller KIND "
                          "(quote a KIND with dots or a colon)"),
        "fou": Key("float", DEFAULT_FOU, 0.0, 0.5, False, "1", hi_open=True,
                   doc="IT2 footprint of uncertainty of the Mamdani sets (0: type-1 shaped; the sets' lower "
                       "membership functions vanish at 0.5)"),
        "type_reduction": Key("str", "bmm", choices=TYPE_REDUCERS, doc="BMM (the paper), Nie–Tan or exact Karnik–Mendel"),
        "psi_error_limit": _f(DEFAULT_PSI_ERROR_LIMIT, 0.0, 100.0, "rad", lo_open=True, doc="clip of the wheel-angle error"),
        "universes": Key("table", recorded_at_default=False, doc=(
            "the Mamdani position and direction controllers' ranges (each input and output is "
            "normalised by its range; beyond it the sets saturate); absent: Table I's, scaled to the "
            "scenario's robot (twin.controllers.robot_settings)"), keys={
            name: Key("float", default, 0.0, 1e6, True, unit, recorded_at_default=False, doc=doc)
            for (name, (default, unit)), doc in zip(UNIVERSES.items(), (
                "position error p_e = p − p_d of the position controller",
                "body pitch rate θ̇, the position controller's second input",
                "lean θ_off, the position controller's output (the balance controller's offset)",
                "heading error α_e = α − α_d of the direction controller",
                "heading rate α̇_e, the direction controller's second input",
                "turning torque u_α per wheel, the direction controller's output"))}),
    }),
    "design": Key("table", keys={
        "epsilon": _f(DEFAULT_EPSILON, MIN_EPSILON, 10.0, "1", doc="radius of the certified initial states (Lemma 2)"),
        "rho": _f(DEFAULT_RHO, 0.0, 1e3, "N·m", lo_open=True, doc="bound on the total wheel torque (Lemma 2)"),
        "decay_rate": _f(DEFAULT_DECAY_RATE, 0.0, 100.0, "1/s", doc="guaranteed decay rate"),
        "max_gain": _f(None, 0.0, 1e6, "", lo_open=True, nullable=True, doc="bound on each gain's norm"),
        "damping": Key("float", DEFAULT_DAMPING, 0.0, 1.0, unit="1", hi_open=True,
                       doc="minimum damping ratio ζ of the closed-loop poles, an LMI conic sector with the decay "
                           "rate (0: none)"),
        "uncertain": Key("map", dict(DEFAULT_UNCERTAIN), 0.0, 1.0, unit="1", hi_open=True,
                         choices=UNCERTAIN_PARAMETERS,
                         doc="robust design: Table III parameter → relative half-range of the box (0.2: ±20 %), "
                             "certified at its corners and the nominal model, sampled inside ({}: the nominal "
                             "model alone)"),
        "all_vertices": Key("bool", DEFAULT_ALL_VERTICES,
                            doc="certify every vertex closed loop A_i + B_i G_j (any controller weights, type-1 "
                                "included), not only the IT2 PDC's own mixes (the paper's Y_ij relaxation)"),
    }),
    "rates": Key("table", keys={
        "physics": _f(1000.0, 10.0, 100000.0, "Hz"),
        "control": _f(200.0, 1.0, 100000.0, "Hz", doc="must divide the physics rate"),
    }),
    "plant": Key("table", doc="the twin's true plant (the controllers and the estimator keep the nominal model)",
                 keys={
        "model": Key("kind", "bullet", role="plant", recorded_at_default=False,
                     doc="bullet: the PyBullet twin (contact, friction, motors, disturbances); analytic: equation (1) "
                         "by RK4 at rates.physics, ideal torque sources (plant.motor does not apply), rolling without "
                         "slip on a level floor (ground, pushes, payload and com_offset at their defaults); or one's "
                         "own, \"package.module:attribute\", called as attribute(config, theta0, alpha0, position, "
                         "**plant.params) (see twin.protocols.Plant)"),
        "params": Key("params", {}, recorded_at_default=False,
                      doc="keyword arguments for a plant.model of one's own"),
        "scale": Key("map", {}, 0.2, 5.0, choices=tuple(PARAMETER_DOCS), unit="×",
                     doc="Table III parameter → factor of its nominal value"),
        "motor": Key("str", "dc", choices=("dc", "ideal"), doc="DC motors with PWM drivers, or ideal torque sources"),
        "payload_mass": _f(0.0, 0.0, 20.0, "kg"),
        "payload_position": Key("vec3", (0.0, 0.0, 0.1), -0.5, 0.5, unit="m", doc="body frame, from the axle; within 0.1 m of the body box"),
        "com_offset": Key("vec3", (0.0, 0.0, 0.0), -0.1, 0.1, unit="m"),
    }),
    "ground": Key("table", keys={
        "slope": _f(0.0, -0.35, 0.35, "rad", doc="floor inclination (positive rises ahead)"),
        "slope_direction": _f(0.0, -math.pi, math.pi, "rad"),
        "lateral_friction": _f(1.0, 0.0, 10.0, "1", lo_open=True),
        "rolling_friction": _f(0.0, 0.0, 1.0, "1"),
        "spinning_friction": _f(0.0, 0.0, 1.0, "1"),
    }),
    "pushes": Key("tables", [], keys=PUSH),
    "sensors": Key("table", keys={
        "sensing": Key("str", "estimated", choices=("estimated", "ideal"),
                       doc="the controllers act on the estimator's output, or read the truth (a reference)"),
        "estimator": Key("kind", "ekf", role="estimator",
                         doc="built-in (ekf, complementary, kalman2, ideal) or 'package.module:attribute' "
                             "(runs that module's code)"),
        "estimator_params": Key("params", {}, recorded_at_default=False,
                                doc="keyword arguments for building the estimator"),
        "imu_rate": _f(200.0, 0.0, 1e5, "Hz", lo_open=True, doc="must divide the control rate"),
        "imu_latency": _f(0.005, 0.0, 1.0, "s", doc="a whole number of control periods"),
        "encoder_counts": Key("int", 1200, 4, 10_000_000, doc="counts per wheel revolution"),
        "encoder_latency": _f(0.0, 0.0, 1.0, "s"),
        "imu": Key("str", "mpu6050", choices=tuple(IMU_PRESETS), recorded_at_default=False,
                   doc="the IMU part whose datasheet figures the gyro and accelerometer take (see "
                       "twin/sensors/specs.py); [sensors.gyro] and [sensors.accel] override single figures"),
        "imu_orientation": Key("vec3", None, -math.pi, math.pi, unit="rad", nullable=True, recorded_at_default=False,
                                doc="how the IMU is mounted: [roll, pitch, yaw] of its axes in the body's (yaw about "
                                    "z, then pitch about the new y, then roll about the newest x; pitch within "
                                    "±π/2): its errors act along its own axes; absent: the body's axes"),
        "imu_position": Key("vec3", None, -1.0, 1.0, unit="m", nullable=True, recorded_at_default=False,
                            doc="IMU sensing point, body frame from the axle midpoint (x forward, y left, z up); "
                                "must lie in the body's box; absent: (0, 0, 0.1)"),
        "gyro": _triad("rad/s", "the preset's"),
        "accel": _triad("m/s²", "the preset's"),
        **{t.name: _sensor_type(t) for t in extra_types()},
        "believed": Key("table", recorded_at_default=False,
                        doc="the specification the estimator believes (its Q and R); absent: the true one",
                        keys={
            "imu": Key("str", None, choices=tuple(IMU_PRESETS), nullable=True, recorded_at_default=False,
                       doc="the part the estimator believes it has; absent: the true sensors' figures"),
            "gyro": _believed_triad("rad/s"),
            "accel": _believed_triad("m/s²"),
        }),
    }),
    "faults": Key("tables", [], keys=FAULT),
    "sweep": Key("table", doc="what 'twin sweep' samples (one draw per sample, shared by every level)", keys={
        "levels": Key("floats", (0.0, 0.1, 0.2, 0.3), 0.0, 0.8,
                      doc="uncertainty levels λ: each perturbed parameter's factor has half-width (uniform) "
                          "or 2σ (normal) of λ"),
        "distribution": Key("str", "uniform", choices=("uniform", "normal"),
                            doc="factor 1 + λ·u, u ~ U(-1, 1); or 1 + λ·z/2, z ~ N(0, 1), clipped to [0.2, 5]"),
        "parameters": Key("names", tuple(n for n in PARAMETER_DOCS if n not in ("g", "n_xb", "r", "b")),
                          choices=tuple(n for n in PARAMETER_DOCS if n not in ("g", "n_xb")),
                          doc="Table III parameters perturbed (on top of plant.scale); the geometry r, b is "
                              "measured, so it is left out unless named"),
        "initial_theta": Key("range", None, -0.99, 0.99, unit="rad", nullable=True,
                             doc="initial pitch drawn uniformly from [low, high]; absent: initial.theta"),
        "push_count": Key("int", 0, 0, 100, doc="random shoves added to the scenario's pushes"),
        "push_force": Key("range", (5.0, 15.0), 0.0, 1e4, unit="N",
                          doc="shove magnitude, uniform; forward or backward with equal odds"),
        "push_window": Key("range", (1.0, 10.0), 0.0, 3600.0, unit="s", doc="shove start time, uniform"),
        "push_duration": _f(0.1, 0.0, 10.0, "s", lo_open=True),
        "push_height": _f(0.12, -1.0, 1.0, "m", doc="point of application above the axle, body frame"),
        "success_settled_for": _f(1.0, 0.0, 3600.0, "s",
                                  doc="success: |θ| below 0.01 rad for at least this long at the end of the run"),
        "success_position_tol": _f(0.05, 0.0, 100.0, "m", lo_open=True,
                                   doc="success: the final position error is within ± this (with a position target)"),
        "success_heading_tol": _f(0.05, 0.0, math.pi, "rad", lo_open=True,
                                  doc="success: the final heading error is within ± this (with a heading target)"),
    }),
    "expect": Key("expect", {}, recorded_at_default=False, recorded=False,
                  doc="bounds on the run's metrics that 'twin check' verifies, e.g. fell = false, "
                      "settling_time_s = \"<= 9\"; [expect.KIND] for one controller, [expect.seeds] over seeds, "
                      "[expect.golden] the tolerances of golden trajectories (see docs/howto/regression.md)"),
    "limits": Key("table", recorded_at_default=False, recorded=False,
                  doc="what a controller or an estimator may cost (each controller's run separately); over a "
                      "limit the run stops with one line naming the plugin and the limit", keys={
        "step_wall_s": Key("float", None, 0.0, 3600.0, True, "s", nullable=True, recorded_at_default=False,
                           doc="wall time one call of the controller, or one step() of the estimator, may take; "
                               "absent: no limit"),
        "run_wall_s": Key("float", None, 0.0, 1e6, True, "s", nullable=True, recorded_at_default=False,
                          doc="wall time one controller's run may take, the twin's own included; absent: no limit"),
        "run_memory_mb": Key("float", None, 0.0, 1e6, True, "MB", nullable=True, recorded_at_default=False,
                             doc="growth of the process's resident memory over one controller's run, in 10⁶ bytes "
                                 "(read every 64 control steps; the run's log takes about 0.4 kB per step); absent: "
                                 "no limit"),
    }),
    "video": Key("table", keys={
        "enabled": Key("bool", True),
        "fps": Key("int", 30, 1, 120),
        "width": Key("int", 640, 64, 3840, unit="px", check=_check_even, doc="even"),
        "height": Key("int", 480, 48, 2160, unit="px", check=_check_even, doc="even"),
        "camera": Key("str", "follow", choices=("follow", "turning", "fixed", "top"), recorded_at_default=False,
                      doc="follow: at a bearing fixed in the world; turning: turns with the heading; fixed: "
                          "still, sees the whole run; top: from above (twin.render.scene.camera_mode)"),
    }),
}


def _where(path: str) -> str:
    return path or "the file"


def _number(v, key: Key, path: str, integer: bool = False):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
        what = "an integer" if integer else "a number"
        raise ScenarioError(f"{path}: must be {what}{_range(key)}, got {shown(v)}")
    if not integer:
        v = float(v)
        if math.isnan(v) or (math.isinf(v) and not (key.hi == math.inf and v > 0)):
            raise ScenarioError(f"{path}: must be a finite number{_range(key)}, got {shown(v)}")
    low_ok = v > key.lo if key.lo_open else v >= key.lo
    high_ok = v < key.hi if key.hi_open else v <= key.hi
    if not (low_ok and high_ok):
        raise ScenarioError(f"{path}: {shown(v)} is out of range; allowed{_range(key)}")
    return v


def _range(key: Key) -> str:
    lo, hi = key.lo, key.hi
    unit = f" {key.unit}" if key.unit else ""
    if math.isinf(lo) and math.isinf(hi):
        return unit and f" in{unit}"
    left = "(" if key.lo_open or math.isinf(lo) else "["
    right = ")" if math.isinf(hi) or key.hi_open else "]"
    fmt = (lambda x: f"{x:g}")
    return f" in {left}{fmt(lo) if not math.isinf(lo) else '-inf'}, {fmt(hi) if not math.isinf(hi) else 'inf'}{right}{unit}"


def parse_value(v, key: Key, path: str):
    k = key.kind
    if k == "float":
        return _number(v, key, path)
    if k == "int":
        n = _number(v, key, path, integer=True)
        if key.check is not None:
            key.check(n, path)
        return n
    if k == "bool":
        if not isinstance(v, bool):
            raise ScenarioError(f"{path}: must be true or false, got {shown(v)}")
        return v
    if k == "str":
        if not isinstance(v, str):
            raise ScenarioError(f"{path}: must be a string{_choices(key)}, got {shown(v)}")
        if key.choices and v not in key.choices:
            raise ScenarioError(f"{path}: {shown(v)} is not allowed{_choices(key)}")
        if key.check is not None:
            key.check(v, path)
        return v
    if k == "vec3":
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise ScenarioError(f"{path}: must be a list of 3 numbers{_range(key)}, got {shown(v)}")
        return tuple(_number(c, key, f"{path}[{i}]") for i, c in enumerate(v))
    if k == "floats":
        if not isinstance(v, (list, tuple)) or not v:
            raise ScenarioError(f"{path}: must be a non-empty list of numbers{_range(key)}, got {shown(v)}")
        return tuple(_number(c, key, f"{path}[{i}]") for i, c in enumerate(v))
    if k == "range":
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            raise ScenarioError(f"{path}: must be [low, high]{_range(key)}, got {shown(v)}")
        lo, hi = (_number(c, key, f"{path}[{i}]") for i, c in enumerate(v))
        if lo > hi:
            raise ScenarioError(f"{path}: low {lo:g} is above high {hi:g}; allowed: [low, high] with low <= high")
        return (lo, hi)
    if k == "names":
        if not isinstance(v, (list, tuple)) or not all(isinstance(c, str) for c in v):
            raise ScenarioError(f"{path}: must be a list of names{_choices(key)}, got {shown(v)}")
        for c in v:
            if c not in key.choices:
                raise ScenarioError(f"{path}: {shown(c)} is not allowed{_choices(key)}")
        if len(set(v)) != len(v):
            raise ScenarioError(f"{path}: names repeat in {shown(list(v))}; allowed: each at most once")
        return tuple(v)
    if k in ("kind", "kinds"):
        items = [v] if k == "kind" else v
        if k == "kinds" and (not isinstance(v, (list, tuple)) or not v):
            raise ScenarioError(f"{path}: must be a non-empty list of {key.role} kinds, got {shown(v)}")
        for i, item in enumerate(items):
            where = path if k == "kind" else f"{path}[{i}]"
            if not isinstance(item, str):
                raise ScenarioError(f"{where}: must be a string naming a {key.role}, got {shown(item)}")
            try:
                check_kind(key.role, item)
            except TwinError as exc:
                raise ScenarioError(f"{where}: {exc}") from None
        if k == "kinds" and len(set(items)) != len(items):
            raise ScenarioError(f"{path}: a kind is repeated in {shown(list(items))}; allowed: each at most once")
        return v if k == "kind" else tuple(items)
    if k == "expect":
        # only for [expect]: twin.scenarios.expectations imports this schema (a cycle at the top)
        from twin.scenarios.expectations import parse_expect

        try:
            parse_expect(v, path)
        except TwinError as exc:
            raise ScenarioError(str(exc)) from None
        return copy.deepcopy(v)
    if k == "params":
        if not isinstance(v, dict):
            raise ScenarioError(f"{path}: must be a table of keyword arguments, got {shown(v)}")
        if key.role:  # one table of keyword arguments per kind: [controller.params.KIND]
            for kind, table in v.items():
                try:
                    check_kind(key.role, kind)
                except TwinError as exc:
                    raise ScenarioError(f"{path}.{key_text(kind)}: {exc}") from None
                if not isinstance(table, dict):
                    raise ScenarioError(f"{path}.{key_text(kind)}: must be a table of keyword arguments for {key.role} "
                                        f"{shown(kind)}, got {shown(table)}")
        return copy.deepcopy(v)
    if k == "table":
        return _table(v, key.keys, path)
    if k == "tables":
        if not isinstance(v, list):
            raise ScenarioError(f"{path}: must be a list of tables ([[{path}]] entries), got {shown(v)}")
        return [_table(item, key.keys, f"{path}[{i}]") for i, item in enumerate(v)]
    if k == "map":
        if not isinstance(v, dict):
            raise ScenarioError(f"{path}: must be a table of name = factor, got {shown(v)}")
        out = {}
        for name, factor in v.items():
            if name not in key.choices:
                raise ScenarioError(f"{path}.{key_text(name)}: unknown parameter; allowed: {', '.join(key.choices)}")
            out[name] = _number(factor, key, f"{path}.{name}")
        return out
    raise AssertionError(k)  # pragma: no cover


def _choices(key: Key) -> str:
    return f" (one of {', '.join(repr(c) for c in key.choices)})" if key.choices else ""


def _table(raw, keys: dict[str, Key], path: str) -> dict:
    if not isinstance(raw, dict):
        raise ScenarioError(f"{_where(path)}: must be a table, got {shown(raw)}")
    for name in raw:
        if name not in keys:
            raise ScenarioError(f"{path + '.' if path else ''}{key_text(name)}: unknown key; allowed here: {', '.join(keys)}")
    out = {}
    for name, key in keys.items():
        p = f"{path}.{name}" if path else name
        if name in raw:
            out[name] = parse_value(raw[name], key, p)
        elif key.kind == "table":
            out[name] = _table({}, key.keys, p)
        elif key.default is REQUIRED:
            raise ScenarioError(f"{p}: missing; it is required")
        else:  # (a copy: a table default such as design.uncertain is not shared between scenarios)
            out[name] = copy.deepcopy(key.default) if isinstance(key.default, dict) else key.default
    return out


def validate(raw: dict) -> dict:
    """The scenario ``raw`` (parsed TOML) with every key checked and every default filled in."""
    check_depth(raw)
    return _table(raw, SCHEMA, "")


def record(data: dict, keys: dict[str, Key] | None = None) -> dict:
    """``data`` as a run records it: keys with ``recorded_at_default=False`` left out while at
    their default (see :class:`Key`)."""
    keys = SCHEMA if keys is None else keys
    out = {}
    for name, value in data.items():
        key = keys.get(name)
        if key is None:
            out[name] = value
        elif not key.recorded or not key.recorded_at_default and _same(value, key.default):
            continue
        elif key.kind == "table" and isinstance(value, dict):
            sub = record(value, key.keys)
            if sub or key.recorded_at_default:  # a table of keys all at their defaults is left out with them
                out[name] = sub
        else:
            out[name] = value
    return out


def _same(value, default) -> bool:
    if isinstance(default, tuple) and isinstance(value, (list, tuple)):
        return tuple(value) == default
    return value == default


def split_key(path: str) -> list[str]:
    """The parts of a dotted key as TOML reads it: bare parts, or quoted ones that may hold dots
    and colons (``controller.params."mylab.ctrl:PID".sign``); a one-line error if it is not one."""
    import tomllib

    try:
        node = tomllib.loads(f"{path} = 0")
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        raise ScenarioError(f"--set {key_text(path)}: not a dotted key; allowed: names joined by dots, a part "
                            f"with dots or colons in double quotes, e.g. controller.params.\"mylab.ctrl:PID\".sign=-1"
                            ) from None
    parts = []
    while isinstance(node, dict) and len(node) == 1:
        (part, node), = node.items()
        parts.append(part)
    return parts


def lookup(path: str) -> Key:
    """The :class:`Key` at dotted ``path`` (for ``--set``); a one-line error if there is none."""
    keys, key = SCHEMA, None
    parts = split_key(path)
    for i, part in enumerate(parts):
        if keys is None or part not in keys:
            where = ".".join(parts[:i]) or "the top level"
            allowed = ", ".join(keys) if keys else "none (not a table)"
            raise ScenarioError(f"--set {key_text(path)}: unknown key {shown(part, 40)} in {where}; allowed: {allowed}")
        key = keys[part]
        if key.kind in ("params", "expect"):  # free-form below: checked as a whole when the file is validated
            return key
        keys = key.keys if key.kind == "table" else (
            {c: Key("float", lo=key.lo, hi=key.hi, unit=key.unit) for c in key.choices} if key.kind == "map" else None)
    return key


def describe() -> list[tuple[str, str, str, str]]:
    """(dotted key, type and range, default, doc) for every key, for the documentation's key reference and --help."""
    rows = []

    def walk(keys, prefix):
        for name, key in keys.items():
            p = f"{prefix}{name}"
            if key.kind == "table":
                walk(key.keys, p + ".")
                continue
            if key.kind == "tables":
                rows.append((f"[[{p}]]", "list of tables", "[]", key.doc))
                walk(key.keys, f"{p}[].")
                continue
            kind = key.kind + (_range(key) if key.kind in ("float", "int", "vec3", "map", "floats", "range")
                               else _choices(key))
            if key.kind == "map" and key.choices:  # its keys: every one the map takes
                kind += f"; keys {', '.join(key.choices)}"
            if key.kind in ("kind", "kinds"):
                kind = f"{key.role} kind" + ("s (list)" if key.kind == "kinds" else "")
            elif key.kind == "params":
                kind = "table (any keys)"
            elif key.kind == "expect":
                kind = "table of bounds"
            if key.default is REQUIRED:
                default = "required"
            elif key.default is None:
                default = "absent"
            elif isinstance(key.default, dict):  # as written in a scenario: a TOML inline table
                default = "{" + ", ".join(f"{k} = {v!r}" for k, v in key.default.items()) + "}"
            else:
                default = repr(key.default)
            rows.append((p, kind, default, key.doc))

    walk(SCHEMA, "")
    return rows
