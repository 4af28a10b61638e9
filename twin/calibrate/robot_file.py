"""The robot ``twin calibrate`` fitted, as a complete robot file (``robot.toml``).

The file starts from the logs' own robot (the robot file a log carries or names: a log written
by ``twin run --log-sensors`` does; else one made of the log's figures: its model, motors,
sensors and rates, see :func:`robot_of_log`) and replaces every quantity the fit identified:
the body's mass, centre of mass, pitch and yaw moments, the drive and ground friction, the
motors' stall torque, no-load speed and dead band (where a log has the duties), the IMU's
latency and its own constant biases and scale-factor errors (as the robot file's fixed device
constants: a run of the fitted robot has them instead of drawing its own). Each fitted value
says its 95 % interval in a comment; a quantity fitted but not identified by the logs keeps
the input robot's value, and its comment says so (a bias or scale of an axis the logs do not
identify, where the input has none, is the fit's estimate, said so too). Everything else (the
wheels, the body's box, the encoders, the rates) is the input robot's, said in the header.

``twin run SCENARIO --robot robot.toml`` runs it.
"""
from __future__ import annotations

import json
import tomllib

from twin.calibrate.output import six_digits
from twin.errors import TwinError
from twin.robots import ROBOT_KEYS, Robot, load_robot
from twin.sensors.specs import preset_name

# fitted parameter → (section, key) of the robot file; the motor's are at the wheel in the fit
SCALARS = {"m_b": ("body", "mass"), "l": ("body", "com_height"), "n_yb": ("body", "pitch_inertia"),
           "n_zb": ("body", "yaw_inertia"), "d_b": ("friction", "drive"), "d_w": ("friction", "ground"),
           "stall_torque": ("drive", "stall_torque"), "no_load_speed": ("drive", "no_load_speed"),
           "dead_band": ("drive", "dead_band"), "imu_latency": ("imu", "latency")}
AXES = "xyz"
VECTORS = {f"{sensor}_{what}_{a}": ("imu", f"{sensor}_{what}", i)
           for sensor in ("gyro", "accel") for what in ("bias", "scale") for i, a in enumerate(AXES)}


def input_robot(log) -> Robot:
    """The robot the log carries or names (its scenario's ``robot``), else :func:`robot_of_log`."""
    scenario = getattr(log, "scenario", None)
    if scenario is not None:
        return scenario.robot
    return robot_of_log(log)


def robot_of_log(log) -> Robot:
    """A robot made of a log's own figures: the model the estimators assume (masses, moments,
    wheels, friction), its motors (the paper's drive where it names none), its IMU (the preset
    part its figures are, else the MPU-6050), encoders and rates. The body's box is Table III's
    drawing rule."""
    p, s = log.model, log.sensors
    paper = load_robot("paper")
    drive = dict(paper.values["drive"], resistance=None, torque_constant=None)
    if log.motor is not None:
        m = log.motor
        drive.update(supply_voltage=m.supply_voltage, stall_torque=m.stall_torque, no_load_speed=m.no_load_speed,
                     gear_ratio=1.0, gear_efficiency=1.0, rotor_inertia=0.0, current_limit=m.current_limit,
                     pwm_bits=m.pwm_bits, dead_band=m.dead_band, inductance=m.inductance,
                     back_emf_compensation=m.back_emf_compensation)
    data = {
        "name": "from-log", "description": f"the robot of the log {log.path}",
        "body": {"mass": p.m_b, "com_height": p.l, "pitch_inertia": p.n_yb, "yaw_inertia": p.n_zb,
                 "roll_inertia": p.n_xb},
        "wheels": {"mass": p.m_w, "radius": p.r, "inertia_axle": p.n_wa, "inertia_diameter": p.n_wd,
                   "track": 2.0 * p.b},
        "friction": {"drive": p.d_b, "ground": p.d_w},
        "drive": {k: v for k, v in drive.items() if v is not None},
        "imu": {"part": preset_name(s.imu.gyro, s.imu.accel) or "mpu6050", "position": list(s.imu.position),
                "rate": s.imu.rate, "latency": s.imu.latency},
        "encoders": {"counts_per_rev": s.encoders.counts_per_rev, "on": "wheel", "latency": s.encoders.latency},
        "control": {"rate": log.control_rate},
    }
    return Robot.from_dict(data, f"the robot of the log {log.path}")


def fitted_values(base: Robot, params: dict) -> tuple[dict, dict]:
    """(the robot file's values: ``base``'s with the identified fits in, a note per changed or
    kept key: (section, key) → comment)."""
    values = {section: dict(keys) for section, keys in base.values.items()}
    d = values["drive"]
    gear = d["gear_ratio"] * d["gear_efficiency"]  # the fit's motor is at the wheel
    notes: dict = {}
    for name, e in params.items():
        where = SCALARS.get(name)
        if where is None:
            continue
        value, (lo, hi), unit = e["value"], e["ci95"], e["unit"]
        if name == "stall_torque":
            value, lo, hi, unit = value / gear, lo / gear, hi / gear, "N·m at the motor"
        elif name == "no_load_speed":
            n = d["gear_ratio"]
            value, lo, hi, unit = value * n, lo * n, hi * n, "rad/s at the motor"
        if e["identifiable"]:
            values[where[0]][where[1]] = six_digits(value)
            notes[where] = f"fitted: 95 % [{_g(lo)}, {_g(hi)}] {unit}"
        else:
            notes[where] = (f"not identified by the logs (fit {_g(value)}, 95 % [{_g(lo)}, {_g(hi)}] {unit}): the "
                            f"input robot's")
    for key in ("gyro_bias", "gyro_scale", "accel_bias", "accel_scale"):
        fits = {i: params[n] for n, (s, k, i) in VECTORS.items() if k == key and n in params}
        if not any(e["identifiable"] for e in fits.values()):
            continue  # nothing known of this constant: runs keep drawing it from the part's spread
        known = base.values["imu"][key]
        vector, said = list(known) if known is not None else [0.0, 0.0, 0.0], []
        kept = "the input robot's" if known is not None else "0"
        for i in range(3):
            e = fits.get(i)
            if e is None:
                said.append(f"{AXES[i]} not fitted ({kept})")
            elif e["identifiable"]:
                vector[i] = six_digits(e["value"])
                said.append(f"{AXES[i]} 95 % [{_g(e['ci95'][0])}, {_g(e['ci95'][1])}]")
            elif known is not None:
                said.append(f"{AXES[i]} not identified: the input robot's")
            else:
                vector[i] = six_digits(e["value"])
                said.append(f"{AXES[i]} not identified: the fit's estimate, 95 % [{_g(e['ci95'][0])}, "
                            f"{_g(e['ci95'][1])}]")
        values["imu"][key] = tuple(vector)
        notes[("imu", key)] = "fitted: " + "; ".join(said)
    return values, notes


def robot_text(base: Robot, params: dict, logs, kind: str) -> str:
    """The fitted robot file (module docstring): ``base`` the input robot, ``params`` the fit
    (each name → value, ci95, unit, identifiable), ``logs`` the logs' paths, ``kind`` the
    calibration's model ("physical" or "twin")."""
    values, notes = fitted_values(base, params)
    unfitted = [n for n in params if n not in SCALARS and n not in VECTORS]
    lines = [f"# Written by 'twin calibrate' from {', '.join(str(p) for p in logs)} ({kind} model).",
             f"# 'twin run SCENARIO --robot robot.toml' runs it. It starts from {base.source}: every figure",
             "# without a 'fitted' comment is that robot's (the logs do not tell it).",
             *(f"# Fitted, not a robot file's figure: {n} (report.json)" for n in unfitted),
             f"name = {json.dumps(base.name + '-fitted')}",
             f"description = {json.dumps('the robot twin calibrate fitted to ' + ', '.join(map(str, logs)))}",
             f"sources = {json.dumps('twin calibrate (report.json has each fit, its interval and correlations)')}"]
    for section, keys in ROBOT_KEYS.items():
        if not section:
            continue
        lines += ["", f"[{section}]"]
        for name in keys:
            if section == "drive" and name in ("resistance", "torque_constant"):
                continue  # the drive is written by its stall torque and no-load speed
            v = values[section][name]
            if v is None:
                continue
            note = notes.get((section, name))
            lines.append(f"{name} = {_toml(v)}" + (f"  # {note}" if note else ""))
    text = "\n".join(lines) + "\n"
    try:  # what it says must be a robot the twin takes
        Robot.from_dict(tomllib.loads(text), "the fitted robot")
    except TwinError as exc:  # the fit stands (report.json); the file would not load: not written, said why
        raise UnfitRobot(f"no robot.toml: the fitted figures with the input robot's others are no robot the twin "
                         f"can run ({' '.join(str(exc).split())})") from None
    return text


class UnfitRobot(TwinError):
    """The fitted figures, with the input robot's others, make a robot the twin refuses (an
    inertia no rigid body has, say): the calibration is written without robot.toml."""


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def _g(v: float) -> str:
    return f"{float(v):.4g}"


__all__ = ["UnfitRobot", "fitted_values", "input_robot", "robot_of_log", "robot_text"]
