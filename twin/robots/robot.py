"""A robot in absolute units, read from a robot file (``robot.toml``), and what the twin makes of it.

Every key has a unit and a range (:data:`ROBOT_KEYS`, the reference page's source); a key left
out takes the paper's robot's figure (Table III and today's drive, sensors and rates), so the
built-in ``paper`` robot is the twin as it always was. Physically impossible inputs are one
line naming the key and the bound: an inertia tensor no rigid body has (a principal moment above
the sum of the other two; a wheel's axle inertia above twice its diameter inertia), a centre of
mass outside the body's box, a drive whose stall torque cannot hold the body even near upright.

The drive is given per side at the motor shaft (stall torque and no-load speed, or resistance and
torque constant, at the supply voltage) with the gear between motor and wheel (ratio, efficiency)
and the rotor's inertia. The twin's motor model (:class:`twin.actuators.DCMotorParams`) acts at the
wheel with one constant k_t = k_e: the wheel sees ``ratio × efficiency`` times the motor's stall
torque and ``1 / ratio`` of its no-load speed, and the rotor's inertia reflected through the gear
(``ratio² × rotor_inertia``) adds to the wheel's axle inertia (and its diameter inertia is raised
to half the axle's where it would otherwise fall below: a rigid body cannot have less; the twin's
wheel is then a thin disc, which over-states its yaw inertia by at most that half). With an efficiency below 1 the
twin's armature current is then ``efficiency`` times the motor's (its torque is right).
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams
from twin.errors import TwinError, shown
from twin.inputs import MAX_TOML_BYTES, read_text
from twin.params import NOMINAL, RobotParams
from twin.plant.urdf import BODY_DEPTH, body_height, body_width
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, IMU_PRESETS, EncoderSpec, ImuSpec

BUILTIN_PACKAGE = "twin.robots.builtin"
HOLD_CHECK_ANGLE = 0.05  # rad: a drive that cannot hold the body even this far from upright is refused


@dataclass(frozen=True)
class Key:
    """One key of a robot file: its unit, its range [lo, hi] (``lo_open``: lo excluded), its
    default (the paper's robot's; None: derived, see the text), and what it is."""

    unit: str
    lo: float
    hi: float
    default: object
    doc: str
    lo_open: bool = True
    kind: str = "number"  # number, integer, vector3, text, bool, choice
    choices: tuple = ()


_P, _M, _I = NOMINAL, DEFAULT_MOTOR, DEFAULT_IMU

# section → key → Key; the order is the reference page's
ROBOT_KEYS: dict[str, dict[str, Key]] = {
    "": {
        "name": Key("", 0, 0, "robot", "the robot's name (a built-in's, or the file's stem)", kind="text"),
        "description": Key("", 0, 0, "", "one line on what the robot is", kind="text"),
        "sources": Key("", 0, 0, "", "where the figures come from (data sheets, measurements, papers)", kind="text"),
    },
    "body": {
        "mass": Key("kg", 0.0, 1000.0, _P.m_b, "the body's mass (everything but the wheels)"),
        "com_height": Key("m", 0.0, 5.0, _P.l, "the body's centre of mass above the wheel axle"),
        "pitch_inertia": Key("kg·m²", 0.0, 1e4, _P.n_yb, "the body's moment about the axis through its centre of "
                             "mass parallel to the axle (y)"),
        "yaw_inertia": Key("kg·m²", 0.0, 1e4, _P.n_zb, "the body's moment about the vertical axis through its "
                           "centre of mass (z)"),
        "roll_inertia": Key("kg·m²", 0.0, 1e4, None, "the body's moment about the forward axis through its centre "
                            "of mass (x); default: the pitch moment (the paper gives none)"),
        "size": Key("m", 0.0, 10.0, None, "the box drawn for the body: depth (x), width (y), height (z); default: "
                    "Table III's drawing rule", kind="vector3"),
        "box_bottom": Key("m", -5.0, 5.0, None, "the box's lowest point above the axle; default: centred on the "
                          "centre of mass", lo_open=False),
    },
    "wheels": {
        "mass": Key("kg", 0.0, 1000.0, _P.m_w, "each wheel's mass (tyre and hub)"),
        "radius": Key("m", 0.0, 2.0, _P.r, "the wheel's rolling radius"),
        "inertia_axle": Key("kg·m²", 0.0, 1e3, _P.n_wa, "each wheel's moment about its axle"),
        "inertia_diameter": Key("kg·m²", 0.0, 1e3, _P.n_wd, "each wheel's moment about a diameter"),
        "track": Key("m", 0.0, 5.0, 2.0 * _P.b, "the distance between the wheels' contact points"),
    },
    "friction": {
        "drive": Key("N·m·s/rad", 0.0, 1e3, _P.d_b, "viscous friction between body and wheel (bearings, gear)",
                     lo_open=False),
        "ground": Key("N·m·s/rad", 0.0, 1e3, _P.d_w, "viscous friction between wheel and ground (rolling)",
                      lo_open=False),
    },
    "drive": {
        "supply_voltage": Key("V", 0.0, 1e4, _M.supply_voltage, "the drivers' supply (the battery)"),
        "stall_torque": Key("N·m", 0.0, 1e4, _M.stall_torque, "the motor's stall torque at the supply voltage, at its "
                            "shaft (before the gear)"),
        "no_load_speed": Key("rad/s", 0.0, 1e5, _M.no_load_speed, "the motor's no-load speed at the supply voltage, "
                             "at its shaft"),
        "resistance": Key("Ω", 0.0, 1e4, None, "armature resistance (with torque_constant, instead of stall_torque "
                          "and no_load_speed)"),
        "torque_constant": Key("N·m/A", 0.0, 1e3, None, "k_t = k_e (with resistance, instead of stall_torque and "
                               "no_load_speed)"),
        "gear_ratio": Key("1", 1.0, 1e4, 1.0, "motor turns per wheel turn", lo_open=False),
        "gear_efficiency": Key("1", 0.0, 1.0, 1.0, "the gear's efficiency: the wheel's torque over ratio × the "
                               "motor's"),
        "rotor_inertia": Key("kg·m²", 0.0, 1.0, 0.0, "the rotor's inertia at the motor shaft (reflected through the "
                             "gear: ratio² times this at the wheel)", lo_open=False),
        "current_limit": Key("A", 0.0, 1e5, None, "the drivers' current limit (default: the stall current)"),
        "pwm_bits": Key("bits", 1, 24, _M.pwm_bits, "the duty's resolution: 2^bits − 1 steps per direction",
                        lo_open=False, kind="integer"),
        "pwm_frequency": Key("Hz", 0.0, 1e7, 20000.0, "the PWM's frequency (recorded; the twin holds the duty's mean)"),
        "dead_band": Key("1", 0.0, 1.0, _M.dead_band, "|duty| below this gives no voltage", lo_open=False),
        "inductance": Key("H", 0.0, 10.0, _M.inductance, "armature inductance (0: the electrical lag left out)",
                          lo_open=False),
        "back_emf_compensation": Key("", 0, 0, _M.back_emf_compensation, "the firmware adds k_e ω to the voltage "
                                     "from the encoders", kind="bool"),
    },
    "imu": {
        "part": Key("", 0, 0, "mpu6050", "the IMU part whose noise and ranges are modelled", kind="choice",
                    choices=tuple(IMU_PRESETS)),
        "position": Key("m", -10.0, 10.0, _I.position, "the IMU's sensing point from the axle midpoint: x forward, "
                        "y left, z up", kind="vector3"),
        "orientation": Key("rad", -math.pi, math.pi, None, "how it is mounted: roll, pitch, yaw of its axes in the "
                           "body's (yaw about z, then pitch about the new y, then roll; default: the body's axes)",
                           lo_open=False, kind="vector3"),
        "rate": Key("Hz", 0.0, 1e5, _I.rate, "the IMU's sample rate (a divisor of the control rate)"),
        "latency": Key("s", 0.0, 1.0, _I.latency, "from a sample to its arrival (whole control periods)",
                       lo_open=False),
        # the device's own constants, where known (a calibration's, or measured on the bench):
        # every run then has them, instead of values drawn from the part's spreads
        "gyro_bias": Key("rad/s", -10.0, 10.0, None, "the gyro's constant bias, x y z, where known (default: "
                         "drawn per run from the part's turn-on spread)", lo_open=False, kind="vector3"),
        "gyro_scale": Key("1", -0.5, 0.5, None, "the gyro's scale-factor errors s, x y z (reading = (1 + s) × "
                          "rate), where known (default: drawn per run)", lo_open=False, kind="vector3"),
        "accel_bias": Key("m/s²", -50.0, 50.0, None, "the accelerometer's constant bias, x y z, where known "
                          "(default: drawn per run)", lo_open=False, kind="vector3"),
        "accel_scale": Key("1", -0.5, 0.5, None, "the accelerometer's scale-factor errors, x y z, where known "
                           "(default: drawn per run)", lo_open=False, kind="vector3"),
    },
    "encoders": {
        "counts_per_rev": Key("counts", 4, 10_000_000, DEFAULT_ENCODERS.counts_per_rev, "quadrature counts per "
                              "revolution of the shaft they sit on", lo_open=False, kind="integer"),
        "on": Key("", 0, 0, "wheel", "the shaft the encoders sit on: the wheel, or the motor (before the gear)",
                  kind="choice", choices=("wheel", "motor")),
        "latency": Key("s", 0.0, 1.0, DEFAULT_ENCODERS.latency, "from a reading to its arrival (whole control "
                       "periods)", lo_open=False),
    },
    "control": {
        "rate": Key("Hz", 0.0, 1e5, 200.0, "the controllers' and the estimator's rate"),
    },
    "limits": {
        "fall_angle": Key("rad", 0.05, 1.5, 1.0, "the tilt at which the robot is lost (the run ends as fallen)",
                          lo_open=False),
    },
}


def _number(where: str, v, k: Key) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise TwinError(f"{where}: must be a number in {k.unit or '1'}, got {shown(v)}")
    lo_ok = v > k.lo if k.lo_open else v >= k.lo
    if not (lo_ok and v <= k.hi):
        bracket = "(" if k.lo_open else "["
        raise TwinError(f"{where}: {v:g} {k.unit} is out of range; allowed in {bracket}{k.lo:g}, {k.hi:g}] {k.unit}"
                        .replace("  ", " "))
    return float(v)


def _value(where: str, v, k: Key):
    if k.kind == "text":
        if not isinstance(v, str):
            raise TwinError(f"{where}: must be text, got {shown(v)}")
        return v
    if k.kind == "bool":
        if not isinstance(v, bool):
            raise TwinError(f"{where}: must be true or false, got {shown(v)}")
        return v
    if k.kind == "choice":
        if v not in k.choices:
            raise TwinError(f"{where}: must be one of {', '.join(k.choices)}, got {shown(v)}")
        return v
    if k.kind == "integer":
        if isinstance(v, bool) or not isinstance(v, int) or not k.lo <= v <= k.hi:
            raise TwinError(f"{where}: must be a whole number from {k.lo:g} to {k.hi:g}, got {shown(v)}")
        return int(v)
    if k.kind == "vector3":
        if not isinstance(v, (list, tuple)) or len(v) != 3:
            raise TwinError(f"{where}: must be 3 numbers in {k.unit}, got {shown(v)}")
        return tuple(_number(f"{where}[{i}]", x, k) for i, x in enumerate(v))
    return _number(where, v, k)


@dataclass(frozen=True)
class Robot:
    """A validated robot: ``values`` section → key → value (every key, defaults filled in;
    ``None`` for a derived default), ``source`` the file (or ``built-in NAME``) it came from."""

    values: dict = field(repr=False)
    source: str = "defaults"

    def __post_init__(self):
        self._check()

    @classmethod
    def from_dict(cls, data: dict, source: str = "robot") -> "Robot":
        """The robot of a robot file's table ``data``; a one-line error naming the key and what is allowed."""
        if not isinstance(data, dict):
            raise TwinError(f"{source}: a robot file is a TOML table, got {shown(data)}")
        values = {}
        for section, keys in ROBOT_KEYS.items():
            given = data if section == "" else data.get(section, {})
            if section and not isinstance(given, dict):
                raise TwinError(f"{source}: [{section}] must be a table, got {shown(given)}")
            out = {}
            for name, k in keys.items():
                where = f"{source}: {section + '.' if section else ''}{name}"
                if name in given:
                    out[name] = _value(where, given[name], k)
                else:
                    out[name] = k.default
            unknown = [n for n in given if n not in keys and not (section == "" and n in ROBOT_KEYS)]
            if unknown:
                where = f"[{section}]" if section else "the file's top level"
                raise TwinError(f"{source}: unknown key {unknown[0]!r} in {where}; allowed: {', '.join(keys)}")
            values[section] = out
        d = values["drive"]
        electric = [n for n in ("resistance", "torque_constant") if n in data.get("drive", {})]
        mechanic = [n for n in ("stall_torque", "no_load_speed") if n in data.get("drive", {})]
        if electric and mechanic:
            raise TwinError(f"{source}: drive: give stall_torque and no_load_speed, or resistance and "
                            f"torque_constant, not both ({', '.join(mechanic + electric)} given)")
        if electric:
            if len(electric) != 2:
                raise TwinError(f"{source}: drive: resistance and torque_constant go together; only {electric[0]} "
                                "is given")
            # the motor's constants → its stall torque and no-load speed at the supply voltage
            d["stall_torque"] = d["torque_constant"] * d["supply_voltage"] / d["resistance"]
            d["no_load_speed"] = d["supply_voltage"] / d["torque_constant"]
        return cls(values, source)

    # ---- what the twin makes of it -------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.values[""]["name"]

    @property
    def description(self) -> str:
        return self.values[""]["description"]

    @functools.cached_property
    def digest(self) -> str:
        """SHA-256 of every figure the twin uses (name, description and sources left out): two
        robots with one digest run the same, whatever their files' layout, comments or names."""
        figures = {k: v for k, v in self.values.items() if k != ""}
        text = json.dumps(figures, sort_keys=True, separators=(",", ":"), default=list)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def params(self) -> RobotParams:
        """The robot as equation (1)'s parameters (the rotor's inertia reflected into the wheel's)."""
        b, w, f, d = self.values["body"], self.values["wheels"], self.values["friction"], self.values["drive"]
        n_wa = w["inertia_axle"] + d["gear_ratio"] ** 2 * d["rotor_inertia"]
        # a rigid wheel's axle moment is at most twice its diameter moment: where the reflected rotor
        # would pass that, the wheel is taken as a thin disc of the moment (the rotor turns with the
        # wheel about the axle; about a diameter it adds what a disc would)
        n_wd = max(w["inertia_diameter"], 0.5 * n_wa)
        n_xb, n_yb, n_zb = b["roll_inertia"], b["pitch_inertia"], b["yaw_inertia"]
        return RobotParams(m_w=w["mass"], m_b=b["mass"], n_wa=n_wa, n_wd=n_wd,
                           n_yb=n_yb, n_zb=n_zb, r=w["radius"], b=0.5 * w["track"], l=b["com_height"], d_b=f["drive"],
                           d_w=f["ground"], n_xb=n_xb, g=NOMINAL.g)

    def model(self, motors: bool = True) -> RobotParams:
        """The model the controllers and the estimator assume (kg, m, kg·m², N·m·s/rad): :meth:`params`,
        and with ``motors`` (the twin drives the wheels through this robot's drive) a driver that
        does not compensate the back-EMF adds the motor's electrical damping k_t k_e / R (at the
        wheel) to the drive's friction ``d_b``: the torque a duty gives then falls with the wheel's
        speed relative to the body exactly as viscous friction between them does, and a design
        that ignored it would ask for torque the drive does not give. A compensating driver (the
        paper's) cancels it: its model is :meth:`params` itself."""
        p = self.params()
        m = self.motor()
        if not motors or m.back_emf_compensation:
            return p
        return p.replace(d_b=p.d_b + m.electrical_damping)

    def motor(self) -> DCMotorParams:
        """Each side's drive as the twin's motor model at the wheel (see the module docstring)."""
        d = self.values["drive"]
        n, eta = d["gear_ratio"], d["gear_efficiency"]
        # the twin's current is efficiency × the motor's (module docstring): so is its limit, or a
        # binding limit would give 1 / efficiency times the torque the real drive gives
        limit = None if d["current_limit"] is None else d["current_limit"] * eta
        return DCMotorParams(supply_voltage=d["supply_voltage"], stall_torque=d["stall_torque"] * n * eta,
                             no_load_speed=d["no_load_speed"] / n, current_limit=limit,
                             pwm_bits=d["pwm_bits"], dead_band=d["dead_band"], inductance=d["inductance"],
                             back_emf_compensation=d["back_emf_compensation"])

    def imu(self) -> ImuSpec:
        i = self.values["imu"]
        gyro, accel = IMU_PRESETS[i["part"]]
        gyro = replace(gyro, bias=i["gyro_bias"], scale=i["gyro_scale"])
        accel = replace(accel, bias=i["accel_bias"], scale=i["accel_scale"])
        return ImuSpec(gyro=gyro, accel=accel, position=i["position"], rate=i["rate"], latency=i["latency"],
                       orientation=i["orientation"] or (0.0, 0.0, 0.0))

    def encoders(self) -> EncoderSpec:
        """The encoders in counts per wheel revolution (on the motor: times the gear ratio)."""
        e = self.values["encoders"]
        n = self.values["drive"]["gear_ratio"] if e["on"] == "motor" else 1.0
        counts = e["counts_per_rev"] * n
        if abs(counts - round(counts)) > 1e-9 * counts:
            raise TwinError(f"{self.source}: encoders on the motor give {counts:g} counts per wheel revolution "
                            f"(counts_per_rev × gear_ratio); allowed: a whole number")
        return EncoderSpec(counts_per_rev=int(round(counts)), latency=e["latency"])

    @property
    def control_rate(self) -> float:
        return self.values["control"]["rate"]

    @property
    def fall_angle(self) -> float:
        return self.values["limits"]["fall_angle"]

    def body_size(self) -> tuple[float, float, float]:
        """(depth, width, height) m of the box drawn for the body."""
        size = self.values["body"]["size"]
        if size is not None:
            return size
        p = self.params()
        return BODY_DEPTH, body_width(p), body_height(p)

    def body_corners(self):
        """The body box's (lowest, highest) corners in m from the axle midpoint, where the file gives
        ``body.size`` or ``body.box_bottom``; None: Table III's drawing rule (the paper's robot)."""
        b = self.values["body"]
        if b["size"] is None and b["box_bottom"] is None:
            return None
        depth, width, height = self.body_size()
        bottom = b["box_bottom"] if b["box_bottom"] is not None else b["com_height"] - 0.5 * height
        return (-0.5 * depth, -0.5 * width, bottom), (0.5 * depth, 0.5 * width, bottom + height)

    def max_hold_angle(self) -> float:
        """rad: the largest tilt at which both motors' stall torque holds the body against gravity
        (π/2 if they hold it lying down)."""
        p, m = self.params(), self.motor()
        ratio = 2.0 * m.stall_torque / (p.m_b * p.g * p.l)
        return math.pi / 2 if ratio >= 1.0 else math.asin(ratio)

    # ---- checks -------------------------------------------------------------------------------
    def _check(self) -> None:
        src = self.source
        b, w = self.values["body"], self.values["wheels"]
        names = ("roll_inertia", "pitch_inertia", "yaw_inertia")
        inertia = (b["roll_inertia"] if b["roll_inertia"] is not None else b["pitch_inertia"], b["pitch_inertia"],
                   b["yaw_inertia"])
        for i in range(3):
            others = sum(inertia) - inertia[i]
            if inertia[i] > others * (1 + 1e-12):
                raise TwinError(f"{src}: body.{names[i]}: {inertia[i]:g} kg·m² exceeds the sum of the other two "
                                f"moments ({others:g} kg·m²), which no rigid body has; allowed: each moment at most "
                                f"the sum of the others")
        if w["inertia_axle"] > 2.0 * w["inertia_diameter"] * (1 + 1e-12):
            raise TwinError(f"{src}: wheels.inertia_axle: {w['inertia_axle']:g} kg·m² exceeds twice inertia_diameter "
                            f"({2 * w['inertia_diameter']:g} kg·m²), which no wheel has (a thin disc has exactly "
                            f"twice); allowed: at most 2 × inertia_diameter")
        depth, width, height = self.body_size()
        bottom = b["box_bottom"] if b["box_bottom"] is not None else b["com_height"] - 0.5 * height
        if not bottom - 1e-12 <= b["com_height"] <= bottom + height + 1e-12:
            raise TwinError(f"{src}: body.com_height: the centre of mass at {b['com_height']:g} m is outside the body's "
                            f"box ({bottom:g} to {bottom + height:g} m above the axle: box_bottom and size); allowed: "
                            f"a centre of mass inside the body")
        if width > w["track"]:
            raise TwinError(f"{src}: body.size: the body's width {width:g} m exceeds the wheels' track "
                            f"{w['track']:g} m; allowed: a body between its wheels")
        if self.max_hold_angle() < HOLD_CHECK_ANGLE:
            m, p = self.motor(), self.params()
            raise TwinError(f"{src}: drive.stall_torque: both motors give {2 * m.stall_torque:.3g} N·m at the wheels "
                            f"(stall torque × gear_ratio × gear_efficiency), which holds the body only "
                            f"{math.degrees(self.max_hold_angle()):.2g}° from upright (m g l = {p.m_b * p.g * p.l:.3g} "
                            f"N·m); allowed: a drive that holds it at least {HOLD_CHECK_ANGLE:g} rad")
        self.encoders()


def robot_item(robot) -> str:
    """``--robot NAME|FILE`` (or an environment's ``robot=``) as the scenario's ``--set`` item:
    a robot file by its absolute path (a worker process, or a scenario file elsewhere, finds it
    all the same), a built-in by its name."""
    path = Path(robot)
    value = str(path.resolve()) if path.suffix == ".toml" and path.is_file() else str(robot)
    return f"robot={json.dumps(value)}"


def builtin_names() -> list[str]:
    """Names of the built-in robots, sorted."""
    return sorted(f.name[:-5] for f in resources.files(BUILTIN_PACKAGE).iterdir() if f.name.endswith(".toml"))


def robot_text(name: str) -> str:
    """A built-in robot's file, to print, copy and edit."""
    if name not in builtin_names():
        raise TwinError(f"no built-in robot {shown(name)}; built-ins: {', '.join(builtin_names())}")
    return resources.files(BUILTIN_PACKAGE).joinpath(f"{name}.toml").read_text(encoding="utf-8")


def builtin_robots() -> dict[str, str]:
    """Built-in name → its one-line description."""
    return {n: tomllib.loads(robot_text(n)).get("description", "") for n in builtin_names()}


@functools.lru_cache(maxsize=None)
def _builtin(name: str) -> Robot:
    """A built-in robot, read and checked once per process (every scenario loads its robot, and
    the paper's to compare with: a built-in's file does not change while the process runs)."""
    data = tomllib.loads(robot_text(name))
    data.setdefault("name", name)
    return Robot.from_dict(data, f"built-in robot {name}")


def load_robot(name_or_path) -> Robot:
    """A built-in robot by name, or a robot file; a one-line error naming the key and what is allowed."""
    if isinstance(name_or_path, Robot):
        return name_or_path
    text_name = str(name_or_path)
    if text_name in builtin_names() and not Path(text_name).suffix:
        return _builtin(text_name)
    path = Path(text_name)
    if path.suffix != ".toml" or not path.is_file():
        raise TwinError(f"no robot {shown(text_name)}: neither a built-in ({', '.join(builtin_names())}) nor a "
                        f".toml file")
    source, stem = str(path), path.stem
    text = read_text(path, MAX_TOML_BYTES, "robot file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TwinError(f"{source}: not valid TOML: {exc}") from None
    data.setdefault("name", stem)
    return Robot.from_dict(data, source)


__all__ = ["HOLD_CHECK_ANGLE", "Key", "ROBOT_KEYS", "Robot", "builtin_names", "builtin_robots", "load_robot",
           "robot_item", "robot_text"]
