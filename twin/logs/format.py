"""The sensor-log format (version 1): what a robot recorded, as an outsider writes it.

A log is a directory::

    log.toml        the manifest (below)
    imu.csv         t, gyro_x, gyro_y, gyro_z, accel_x, accel_y, accel_z      s, rad/s, m/s²
    encoders.csv    t, left, right                                             s, counts (integers)
    commands.csv    t, ul, ur                                                  s, N·m (or PWM duty)
    truth.csv       t, theta, theta_dot, psi, psi_dot, alpha, alpha_dot        s, rad, rad/s (optional)
                    [, psi_l, psi_r, gyro_bias_x, gyro_bias_y, gyro_bias_z]    rad, rad/s (optional)
    duty.csv        t, duty_l, duty_r                                          s, 1 (PWM duty in [-1, 1]; optional)

Every stream's ``t`` is in seconds on one clock shared by all streams: for a reading, when it
became available to the estimator (on a robot, when the control loop read it); for a command,
the control instant it was computed at (applied until the next one). Axes are the body's, as in
:mod:`twin.protocols`: x forward, y along the axle to the left, z up the body; at rest and
upright the accelerometer reads +g on z. Encoders count since power-up, each the wheel's angle
relative to the body (counts_per_rev per revolution), forward positive.

Timing: rows need not be regular. Rows are read in time order; a row up to
:data:`TIME_TOLERANCE` s earlier than the one before it counts as simultaneous, one earlier
than that is an error; simultaneous rows of a stream (duplicated timestamps) are kept in file
order, and the last one reaching the estimator at an instant is the one it gets. An empty
reading (gyro, accel, left and right, or a truth row) means nothing arrived of it; a gap is
simply no rows. NaN and infinities are errors.

``log.toml``::

    format = "mtwip-sensor-log"
    version = 1
    control_rate = 200.0          # Hz: the commands' (and the estimator's) rate
    wheel_radius = 0.04           # m
    track = 0.30                  # m, between the wheels' contact points (2b)
    encoder_counts = 1200         # counts per wheel revolution
    imu_position = [0.0, 0.0, 0.1]  # m, body axes, from the axle midpoint
    initial_heading = 0.0         # rad, α at the first command (optional, default 0)
    scenario = "paper-exp1"       # optional: a built-in, or a .toml file beside log.toml, whose
    set = ["sensors.imu=\\"mpu6050\\""]  # [sensors] (with these --set items) give the sensors'
                                  # specification and [plant.motor] the motors; default: the defaults
    [robot]                       # optional: the model the estimators assume, twin.params.RobotParams
    m_b = 2.58                    # keys in SI (default Table III; r and b come from the keys above)
    [motor]                       # optional: the motors and drivers (twin.actuators.DCMotorParams keys,
    stall_torque = 1.2            # SI; default the scenario's plant.motor), for "duty" commands and the EKF
    [commands]
    unit = "N·m"                  # or "duty": PWM duty in [-1, 1], torque = duty × the motor's stall torque
    [units]                       # optional; if given, exactly these
    time = "s"
    gyro = "rad/s"
    accel = "m/s^2"
    encoders = "counts"
    commands = "N·m"              # or "duty"
    [truth]                       # optional: the sensors' true constants (see "State truth" below)
    gyro_scale = [0.0, 0.003, -0.001]    # scale-factor errors, x y z (reading = (1 + s) × rate + bias)
    accel_scale = [0.002, 0.0, -0.004]   # x y z
    encoder_phase = [0.31, 0.77]         # counts: where each encoder's first edge lies in a count, left right
    wheel_radius = 0.0401                # m: the true radius (the manifest's is the model's)

State truth (optional, for the EKF's NEES in ``twin replay``): the EKF estimates 12 states, six
of which the truth columns above do not give. A log may add, all together, five truth columns
``psi_l, psi_r`` (rad, each wheel's absolute angle, forward positive) and ``gyro_bias_x,
gyro_bias_y, gyro_bias_z`` (rad/s, the gyro's true bias in the sample of that instant; empty
where no sample was taken), and the ``[truth]`` table of the sensors' constants. The twin writes
both (``twin run --log-sensors``); a robot's log with motion capture usually has neither, and
then replay reports no NEES (NIS and whiteness need no truth).

Applied duty (optional ``duty.csv``): the PWM duty the motor driver actually applied to each
motor, dimensionless in [-1, 1] (forward positive; 1 is the full supply voltage), held over the
control period starting at ``t``. It is the duty *after* everything the driver does to a
command: the current limit, back-EMF compensation at the shaft speed it measured, the supply's
clip to [-1, 1], the dead band (a duty inside it is written as 0: no voltage reached the motor)
and the PWM resolution (the twin's duty is a whole number of 2^bits - 1 steps). That is the
duty :class:`twin.actuators.dc_motor.MotorDriver` returns and the motor model turns into a
voltage (τ_0 = duty × stall torque, less the back-EMF slope), so the motor's own figures can be
fitted from it; a torque command (commands.csv in N·m) is what the controller asked for, before
the driver. Each row's ``t`` must equal (within :data:`TIME_TOLERANCE`) the ``t`` of a row of
commands.csv: one row per control period, a subset of the control instants allowed (a robot
that recorded the duty at fewer instants, or lost some rows: the periods without a row have no
known duty, nothing is held across them); times strictly increasing (one duty per period, no
duplicated instant). The twin writes it for runs with DC motors (``plant.motor = "dc"``), one
row per command, and none for ideal torque sources; logs without it read as before
(:attr:`SensorLog.duty` None), and the format stays version 1 (a reader that does not know
duty.csv ignores it). It is independent of ``[commands] unit``: with unit = "duty",
commands.csv holds what the controller commanded as a duty, duty.csv what was applied.

Anything wrong that can be detected is one :class:`~twin.errors.TwinError` line naming the
file (and the row or key) and what is allowed: a missing manifest or stream, an unknown format
or version, an unknown key, non-numeric or non-finite values, counts that are not integers, time
that runs backwards, an accelerometer in g rather than m/s², gravity on another axis than z.

A log is input from outside, read as such: what it may ask for is bounded
(:mod:`twin.logs.bounds`: a stream's bytes, rows and row length, |t|, a stream's span, the
replay's control instants, a count's digits, the manifest's size and nesting), each bound
checked on the row that exceeds it before anything is allocated from it; its files are read only
if they are regular files (:func:`twin.inputs.open_regular`: a FIFO or ``/dev/zero`` is refused
unread) inside the log's directory (:func:`twin.inputs.inside`: a symbolic link out of it is
refused unopened, so no message quotes another file). "Beside log.toml" means that: a
``scenario`` file is a file name alone in the log's directory, and its bases lie there too.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twin.errors import TwinError, shown
from twin.inputs import inside, read_text, toml_loads
from twin.logs.bounds import MAX_INSTANTS, MAX_MANIFEST_BYTES

FORMAT = "mtwip-sensor-log"
VERSION = 1
TIME_TOLERANCE = 1e-6  # s: a row this much earlier than the previous one counts as simultaneous
STREAMS = {
    "imu": ("t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"),
    "encoders": ("t", "left", "right"),
    "commands": ("t", "ul", "ur"),
    "truth": ("t", "theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot"),
    "duty": ("t", "duty_l", "duty_r"),
}
TRUTH_STATE = ("psi_l", "psi_r", "gyro_bias_x", "gyro_bias_y", "gyro_bias_z")  # optional truth.csv columns
# the optional [truth] table: key -> (length, what; None: a scalar number)
TRUTH_KEYS = {"gyro_scale": (3, "gyro scale-factor errors x, y, z"),
              "accel_scale": (3, "accelerometer scale-factor errors x, y, z"),
              "encoder_phase": (2, "counts: each encoder's first edge within a count, left, right"),
              "wheel_radius": (None, "m: the true wheel radius")}
REQUIRED = ("imu", "encoders", "commands")
UNITS = {"time": "s", "gyro": "rad/s", "accel": "m/s^2", "encoders": "counts"}
COMMAND_UNITS = ("N·m", "duty")
_KEYS = {"format", "version", "control_rate", "wheel_radius", "track", "encoder_counts", "imu_position",
         "initial_heading", "scenario", "set", "robot", "commands", "units", "source", "expect", "truth", "motor"}


@dataclass(frozen=True)
class SensorLog:
    """A log as read (:func:`read_log`): its manifest's figures and the streams as arrays.

    ``imu_t`` (n,) s with ``gyro`` (n, 3) rad/s and ``accel`` (n, 3) m/s², NaN rows where a
    row held none; ``encoders_t`` (m,) s with ``counts`` (m, 2) int64 (``has_counts`` (m,)
    where a row held them); ``commands_t`` (k,) s with ``commands`` (k, 2) N·m (duty
    converted); ``truth_t`` and ``truth`` (j, 6) [θ, θ̇, ψ, ψ̇, α, α̇] or None;
    ``truth_state`` (j, 5) [ψ_l, ψ_r rad, gyro bias x, y, z rad/s] where truth.csv has those
    columns, else None, and ``truth_constants`` the manifest's ``[truth]`` table (a dict of
    floats and tuples), else None; ``duty_t`` (d,) s and ``duty`` (d, 2) [left, right] the
    PWM duty the drivers applied (dimensionless, [-1, 1], after the dead band; see the module
    docstring) where the log has duty.csv, else None."""

    path: Path
    manifest: dict
    control_rate: float
    model: object  # RobotParams: the model the estimators assume
    sensors: object  # SensorConfig: the sensors as the estimators believe them
    motor: object  # DCMotorParams or None
    initial_heading: float
    imu_t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    encoders_t: np.ndarray
    counts: np.ndarray
    has_counts: np.ndarray
    commands_t: np.ndarray
    commands: np.ndarray
    truth_t: np.ndarray | None = None
    truth: np.ndarray | None = None
    scenario: object = field(default=None, repr=False)  # the Scenario the manifest names, if any
    truth_state: np.ndarray | None = None
    truth_constants: dict | None = None
    duty_t: np.ndarray | None = None
    duty: np.ndarray | None = None

    @property
    def counts_per_rev(self) -> int:
        return int(self.manifest["encoder_counts"])

    @property
    def duration(self) -> float:
        """s from the first command to the last."""
        return float(self.commands_t[-1] - self.commands_t[0])

    def context(self):
        """The :class:`twin.registry.BuildContext` an estimator is built with for this log."""
        from twin.protocols import Targets
        from twin.registry import BuildContext

        return BuildContext(self.control_rate, self.model, self.estimator_motor(), self.sensors, Targets(),
                            self.initial_heading)

    def estimator_motor(self):
        """The motors as an estimator is told them, for the commands it is handed (:attr:`commands`).

        N·m commands are the controller's: the estimator's model (:class:`estimation.model.
        EstimatorModel`) turns them into the held torque τ_0 as the driver does (current limit,
        back-EMF compensation at the shaft speed, the stall torque), so it gets :attr:`motor` as it
        is. Commands logged as a PWM duty are already past the driver: duty × stall torque *is*
        τ_0, the compensation included; with the driver's compensation on and its current limit
        left in, the model would add c_e ω a second time (and clip τ_0 with a limit that acted on
        the command). So for them the estimator gets the same motor without back-EMF compensation
        and with the current limit at the stall current: the model then hands τ_0 through
        unchanged (clipped to the stall torque, which |duty| ≤ 1 never reaches), and keeps the
        back-EMF slope c_e on the body-wheel damping, where it physically acts."""
        from dataclasses import replace

        unit = (self.manifest.get("commands") or {}).get("unit", "N·m")
        if unit != "duty" or self.motor is None:
            return self.motor
        if not self.motor.back_emf_compensation and self.motor.current_limit is None:
            return self.motor
        return replace(self.motor, back_emf_compensation=False, current_limit=None)


# ---- reading ---------------------------------------------------------------------------------------
def read_log(path) -> SensorLog:
    """The log in directory ``path``, checked (see the module docstring)."""
    from twin.params import NOMINAL, RobotParams

    root = Path(path)
    if not root.is_dir():  # (False for a name with a null character too)
        name = str(root) if str(root).isprintable() else shown(str(root))
        raise TwinError(f"{name}: not a sensor log (a directory holding log.toml and the streams)")
    mfile = root / "log.toml"
    try:  # the log's own file (inside its directory), a regular file, at most MAX_MANIFEST_BYTES
        inside(mfile, root, "manifest")
        text = read_text(mfile, MAX_MANIFEST_BYTES, "sensor log's manifest (log.toml)")
    except FileNotFoundError:
        raise TwinError(f"{mfile}: missing; a sensor log's manifest says format = \"{FORMAT}\", version, "
                        f"control_rate, wheel_radius, track, encoder_counts and imu_position") from None
    try:
        m = toml_loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TwinError(f"{mfile}: not valid TOML ({' '.join(str(exc).split())})") from None
    except ValueError as exc:  # TooDeep, or an integer beyond Python's 4300-digit conversion
        raise TwinError(f"{mfile}: cannot be read: {exc}; allowed: a manifest as documented "
                        f"(docs/howto/robot-logs.md)") from None
    where = str(mfile)
    if m.get("format") != FORMAT:
        raise TwinError(f"{where}: format: {shown(m.get('format'))} is not a sensor log's; allowed: \"{FORMAT}\"")
    if m.get("version") != VERSION:
        raise TwinError(f"{where}: version: {shown(m.get('version'))} is not known here; allowed: {VERSION} "
                        f"(a newer twin may read it)")
    unknown = sorted(set(m) - _KEYS)
    if unknown:
        raise TwinError(f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_KEYS))}")
    rate = _number(m, "control_rate", where, 0.0, 1e5, "Hz", lo_open=True)
    radius = _number(m, "wheel_radius", where, 0.0, 1.0, "m", lo_open=True)
    track = _number(m, "track", where, 0.0, 5.0, "m", lo_open=True)
    heading = _number(m, "initial_heading", where, -1e3, 1e3, "rad", default=0.0)
    counts = m.get("encoder_counts")
    if isinstance(counts, bool) or not isinstance(counts, int) or not 4 <= counts <= 10_000_000:
        raise TwinError(f"{where}: encoder_counts: {shown(counts)}; allowed: an integer from 4 to 10000000 "
                        f"(counts per wheel revolution)")
    pos = m.get("imu_position")
    if not (isinstance(pos, list) and len(pos) == 3 and all(_is_number(v) and abs(v) <= 1.0 for v in pos)):
        raise TwinError(f"{where}: imu_position: {shown(pos)}; allowed: [x, y, z] in m, body axes from the "
                        f"axle midpoint, each within ±1 m")
    units = m.get("units", {})
    if not isinstance(units, dict):
        raise TwinError(f"{where}: units must be a table, got {shown(units)}")
    c = m.get("commands", {})
    if not isinstance(c, dict) or set(c) - {"unit"}:
        raise TwinError(f"{where}: commands: a table with unit = \"N·m\" or \"duty\", got {shown(c)}")
    cunit = c.get("unit", "N·m")
    if cunit not in COMMAND_UNITS:
        raise TwinError(f"{where}: commands.unit: {shown(cunit)}; allowed: {', '.join(map(repr, COMMAND_UNITS))}")
    for k, v in units.items():
        want = cunit if k == "commands" else UNITS.get(k)
        if want is None:
            raise TwinError(f"{where}: units.{k}: unknown stream quantity; allowed: "
                            f"{', '.join(list(UNITS) + ['commands'])}")
        if v != want:
            raise TwinError(f"{where}: units.{k}: {shown(v)}; allowed: {want!r} (the format's units are SI: convert "
                            f"when writing the log)")

    scenario = _scenario(root, m, where, counts, pos)
    robot = m.get("robot", {})
    if not isinstance(robot, dict):
        raise TwinError(f"{where}: robot must be a table of twin.params.RobotParams keys, got {shown(robot)}")
    for k in ("r", "b"):
        if k in robot:
            raise TwinError(f"{where}: robot.{k}: give it as {'wheel_radius' if k == 'r' else 'track (= 2 b)'}")
    try:
        fields = {**{k: getattr(NOMINAL, k) for k in NOMINAL.__dataclass_fields__ if k != "n_xb"}, **robot,
                  "r": radius, "b": track / 2.0}
        if "n_xb" in robot:
            fields["n_xb"] = robot["n_xb"]
        model = RobotParams(**fields)
    except TypeError as exc:
        raise TwinError(f"{where}: robot: {' '.join(str(exc).split())}; allowed keys: "
                        f"{', '.join(k for k in NOMINAL.__dataclass_fields__ if k not in ('r', 'b'))}") from None
    except TwinError as exc:
        raise TwinError(f"{where}: robot: {exc}") from None
    sensors = scenario.believed_sensor_config()
    if sensors is None:
        raise TwinError(f"{where}: scenario: its sensors.sensing is \"ideal\"; a log holds readings: the scenario "
                        f"must have simulated sensors")
    motor = scenario.twin_config().motor
    if "motor" in m:  # the robot's motors and drivers: twin.actuators.DCMotorParams keys, SI
        from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams

        table = m["motor"]
        if not isinstance(table, dict):
            raise TwinError(f"{where}: motor must be a table of twin.actuators.DCMotorParams keys, got {shown(table)}")
        try:
            motor = DCMotorParams(**{**{k: getattr(motor or DEFAULT_MOTOR, k)
                                        for k in DCMotorParams.__dataclass_fields__}, **table})
        except TypeError:
            bad = sorted(set(table) - set(DCMotorParams.__dataclass_fields__))
            raise TwinError(f"{where}: motor.{bad[0] if bad else '?'}: unknown; allowed: "
                            f"{', '.join(DCMotorParams.__dataclass_fields__)}") from None
        except TwinError as exc:
            raise TwinError(f"{where}: motor: {exc}") from None
    if cunit == "duty" and motor is None:
        raise TwinError(f"{where}: commands.unit = \"duty\" needs the motor's figures (the scenario's "
                        f"plant.motor = \"dc\")")

    imu = _stream(root, "imu", required=True)
    enc = _stream(root, "encoders", required=True, integers=True)
    cmd = _stream(root, "commands", required=True, need_all=True)
    tru = _stream(root, "truth", required=False)
    duty = _stream(root, "duty", required=False, need_all=True)
    constants = _truth_table(m.get("truth"), where) if "truth" in m else None
    t_imu, gyro, accel = imu[:, 0], imu[:, 1:4], imu[:, 4:7]
    _check_gravity(root / "imu.csv", accel, t_imu)
    ecount = enc[:, 1:3]
    has = np.isfinite(ecount).all(axis=1)
    counts_i = np.zeros(ecount.shape, dtype=np.int64)
    counts_i[has] = ecount[has].astype(np.int64)
    commands = cmd[:, 1:3]
    if cunit == "duty":
        if np.any(np.abs(commands) > 1.0):
            row = int(np.argmax((np.abs(commands) > 1.0).any(axis=1)))
            raise TwinError(f"{root / 'commands.csv'}: row {row + 2}: a PWM duty outside [-1, 1]")
        commands = commands * motor.stall_torque
    if len(cmd) < 2:
        raise TwinError(f"{root / 'commands.csv'}: {len(cmd)} row(s); a log needs at least 2 control instants")
    _check_instants(root / "commands.csv", cmd[:, 0], rate)
    if duty is not None:
        _check_duty(root / "duty.csv", duty, cmd[:, 0])
    return SensorLog(root, m, rate, model, sensors, motor, heading, t_imu, gyro, accel, enc[:, 0], counts_i, has,
                     cmd[:, 0], commands, None if tru is None else tru[:, 0], None if tru is None else tru[:, 1:7],
                     scenario, None if tru is None or tru.shape[1] == 7 else tru[:, 7:], constants,
                     None if duty is None else duty[:, 0], None if duty is None else duty[:, 1:3])


def _check_instants(path: Path, t: np.ndarray, rate: float) -> None:
    """The replay's control instants, one per 1/``rate`` s from the first command to the last
    (:func:`twin.logs.replay.instants`), at most :data:`~twin.logs.bounds.MAX_INSTANTS`: checked
    here, in floating point, before anything is allocated per instant (a stray row at t = 1e9 s
    would ask for 2·10¹¹ of them at 200 Hz)."""
    span = (t - t[0]) * rate  # control periods from the first command (|t| is bounded: no overflow)
    over = np.flatnonzero(span > MAX_INSTANTS - 1)
    if over.size:
        row = int(over[0])
        raise TwinError(f"{path}: row {row + 2}: t = {float(t[row])!r} s is {float(span[row]):.6g} control periods "
                        f"after the first command (t = {float(t[0])!r} s, {rate:g} Hz); allowed: a replay of at most "
                        f"{MAX_INSTANTS:,} control instants ({(MAX_INSTANTS - 1) / rate:.6g} s at this rate; split "
                        f"a longer log)")


def _check_duty(path: Path, duty: np.ndarray, commands_t: np.ndarray) -> None:
    """duty.csv's rows (see the module docstring): each duty in [-1, 1], each time that of a
    command row (within :data:`TIME_TOLERANCE`), strictly increasing."""
    bad = np.abs(duty[:, 1:3]) > 1.0
    if bad.any():
        row = int(np.argmax(bad.any(axis=1)))
        col = STREAMS["duty"][1 + int(np.argmax(bad[row]))]
        raise TwinError(f"{path}: row {row + 2}: {col} = {float(duty[row, 1 + int(np.argmax(bad[row]))])!r} is outside "
                        f"[-1, 1]; allowed: the PWM duty as a fraction of the supply voltage")
    t = duty[:, 0]
    if len(t) > 1:
        dup = np.flatnonzero(np.diff(t) <= TIME_TOLERANCE)
        if dup.size:
            row = int(dup[0]) + 1
            raise TwinError(f"{path}: row {row + 2}: t = {float(t[row])!r} s repeats the row before's instant; "
                            f"allowed: one duty per control period (times strictly increasing)")
    # the command row nearest each duty row's time (commands.csv is in time order, up to its tolerance)
    k = np.clip(np.searchsorted(commands_t, t), 1, len(commands_t) - 1)
    near = np.minimum(np.abs(commands_t[k - 1] - t), np.abs(commands_t[k] - t))
    off = np.flatnonzero(near > TIME_TOLERANCE)
    if off.size:
        row = int(off[0])
        raise TwinError(f"{path}: row {row + 2}: t = {float(t[row])!r} s is no control instant of commands.csv; "
                        f"allowed: the t of a commands.csv row (within {TIME_TOLERANCE:g} s), one duty row per "
                        f"control period (a subset of them may be given)")


def _truth_table(t, where: str) -> dict:
    """The manifest's optional ``[truth]`` table, checked: every key of :data:`TRUTH_KEYS`."""
    if not isinstance(t, dict):
        raise TwinError(f"{where}: truth must be a table ({', '.join(TRUTH_KEYS)}), got {shown(t)}")
    unknown = sorted(set(t) - set(TRUTH_KEYS))
    if unknown:
        raise TwinError(f"{where}: truth.{unknown[0]}: unknown key; allowed: {', '.join(TRUTH_KEYS)}")
    out = {}
    for k, (n, what) in TRUTH_KEYS.items():
        v = t.get(k)
        ok = (_is_number(v) and 0.0 < v <= 1.0) if n is None else (
            isinstance(v, list) and len(v) == n and all(_is_number(e) for e in v))
        if not ok:
            want = "a number in (0, 1]" if n is None else f"a list of {n} numbers"
            raise TwinError(f"{where}: truth.{k}: {'missing' if v is None else shown(v)}; allowed: {want} ({what})")
        out[k] = float(v) if n is None else tuple(float(e) for e in v)
    return out


def _is_number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def _number(m: dict, key: str, where: str, lo: float, hi: float, unit: str, lo_open=False, default=None) -> float:
    v = m.get(key, default)
    ok = _is_number(v) and (lo < v if lo_open else lo <= v) and v <= hi
    if not ok:
        what = "missing" if v is None else shown(v)
        raise TwinError(f"{where}: {key}: {what}; allowed: a number in {'(' if lo_open else '['}{lo:g}, {hi:g}] {unit}")
    return float(v)


def _scenario(root: Path, m: dict, where: str, counts: int, pos):
    """The scenario the manifest names (default: the defaults), with its ``set`` items and the
    manifest's encoder counts and IMU position."""
    from twin.scenarios import load_scenario

    name = m.get("scenario", "paper-exp1")
    items = m.get("set", [])
    beside = "a built-in name or the name of a .toml file beside log.toml (no directory: the log's own file)"
    if not isinstance(name, str) or not name:
        raise TwinError(f"{where}: scenario: {shown(name)}; allowed: {beside}")
    if not (isinstance(items, list) and all(isinstance(s, str) for s in items)):
        raise TwinError(f"{where}: set: {shown(items)}; allowed: a list of \"KEY=VALUE\" strings (as --set takes)")
    if name.endswith(".toml"):
        # "beside log.toml": a file name alone, never a path out of the log's directory ("../x.toml",
        # "/etc/x.toml"); what it or its bases resolve to through symbolic links must stay inside too
        if Path(name).name != name or "\\" in name or not name.isprintable():
            raise TwinError(f"{where}: scenario: {shown(name)} is not beside log.toml; allowed: {beside}")
        name = str(root / name)
    items = [*items, f"sensors.encoder_counts={counts}", f"sensors.imu_position=[{', '.join(map(repr, pos))}]",
             "sensors.sensing=\"estimated\""]
    try:
        return load_scenario(name, items, within=root)
    except TwinError as exc:
        raise TwinError(f"{where}: scenario: {exc}") from None


def _stream(root: Path, name: str, required: bool, integers: bool = False, need_all: bool = False):
    """Stream ``name`` as a float array (rows, columns), in file order; None if absent and optional.

    The log's own file only: one that leads out of the log's directory (a symbolic link to
    another file) is refused before it is opened; read row by row within the bounds of
    :mod:`twin.logs.bounds` (:func:`twin.logs.streams.read_stream`)."""
    from twin.logs.streams import read_stream

    path = root / f"{name}.csv"
    cols = STREAMS[name]
    groups = {"imu": ((1, 4), (4, 7)), "encoders": ((1, 3),), "commands": ((1, 3),), "truth": ((1, 7),),
              "duty": ((1, 3),)}[name]
    layouts = [(cols, groups)]
    if name == "truth":  # the optional state truth (see the docstring)
        layouts.append((cols + TRUTH_STATE, ((1, 7), (7, 9), (9, 12))))
    also = f" (optionally followed by {','.join(TRUTH_STATE)})" if name == "truth" else ""
    try:
        inside(path, root, "stream")
        out, _ = read_stream(path, layouts, tolerance=TIME_TOLERANCE, integers=integers, need_all=need_all,
                             also=also)
    except FileNotFoundError:
        if required:
            raise TwinError(f"{path}: missing; a sensor log needs {', '.join(s + '.csv' for s in REQUIRED)} "
                            f"(truth.csv and duty.csv are optional)") from None
        return None
    return out


def _check_gravity(path: Path, accel: np.ndarray, t: np.ndarray) -> None:
    """The accelerometer's mean over its first 0.1 s of readings (the robot at rest): about g, mostly on +z."""
    ok = np.isfinite(accel).all(axis=1)
    if not ok.any():
        raise TwinError(f"{path}: no accelerometer reading; the estimators start from gravity's direction")
    first = ok & (t <= t[ok][0] + 0.1)
    mean = accel[first].mean(axis=0)
    norm = float(np.linalg.norm(mean))
    row = int(np.flatnonzero(ok)[0]) + 2
    if 0.5 <= norm <= 2.0:
        raise TwinError(f"{path}: rows from {row}: the accelerometer reads {norm:.3g} on average, gravity in g; "
                        f"allowed: m/s² (multiply by 9.80665)")
    if not 5.0 <= norm <= 15.0:
        raise TwinError(f"{path}: rows from {row}: the accelerometer reads {norm:.3g} m/s² on average over the "
                        f"first 0.1 s; allowed: about 9.8 m/s² (the robot starts at rest)")
    axis = int(np.argmax(np.abs(mean)))
    if axis != 2 or mean[2] <= 0:
        name = "xyz"[axis]
        raise TwinError(f"{path}: rows from {row}: gravity is on {'-' if mean[axis] < 0 else '+'}{name} "
                        f"({mean[axis]:+.3g} m/s²); allowed: body axes with z up (+g on accel_z at rest, upright)")


# ---- writing ---------------------------------------------------------------------------------------
def write_log(run, out, scenario=None, initial_heading: float | None = None, source: str = "twin run") -> Path:
    """Write twin run ``run`` (a :class:`twin.sim.runs.Run` logged at every control step, with
    simulated sensors) as a sensor log in directory ``out``, the truth stream included.

    ``scenario``: the :class:`~twin.scenarios.Scenario` it ran (its name or file, and --set
    items, go into log.toml, so the estimators are built for the same sensors and motors);
    ``initial_heading`` (rad): α at t = 0 as the run's estimator was told it (default: the
    scenario's ``initial.alpha``, else the truth's first α); ``source``: what wrote it (log.toml's
    free-text ``source``; a sweep's sample adds which sample it is). A run with DC motors also
    gets duty.csv, the duty its drivers applied (``run.signal("duty_l")``, ``"duty_r"``)."""
    if run.measurements is None or run.sensor_config is None:
        raise TwinError("a sensor log needs a run with simulated sensors (sensing is ideal here)")
    if getattr(run, "log_every", 1) != 1:
        raise TwinError(f"a sensor log needs every control step (log_every = 1), got {run.log_every}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg, sensors = run.config, run.sensor_config
    heading = initial_heading if initial_heading is not None else (
        scenario.data["initial"]["alpha"] if scenario is not None else float(run.signal("alpha")[0]))
    ms = run.measurements
    res = 1.0 / (sensors.encoders.counts_per_rev / (2.0 * math.pi))  # as the twin's encoders (twin.sensors.suite)
    with open(out / "imu.csv", "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(STREAMS["imu"]) + "\n")
        for i in np.flatnonzero(ms.has_gyro | ms.has_accel):
            g = [repr(float(v)) for v in ms.gyro[i]] if ms.has_gyro[i] else ["", "", ""]
            a = [repr(float(v)) for v in ms.accel[i]] if ms.has_accel[i] else ["", "", ""]
            fh.write(",".join([repr(float(ms.t[i])), *g, *a]) + "\n")
    with open(out / "encoders.csv", "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(STREAMS["encoders"]) + "\n")
        for i in np.flatnonzero(ms.has_encoders):
            c = [round(float(v) / res) for v in ms.encoders[i]]
            if any(k * res != float(v) for k, v in zip(c, ms.encoders[i])):
                raise TwinError(f"the twin's encoder reading at t = {ms.t[i]:g} s is not a whole number of counts "
                                f"(an encoder spike fault adds an angle): it cannot be written as counts")
            fh.write(f"{float(ms.t[i])!r},{c[0]},{c[1]}\n")
    ul, ur = run.signal("ul_cmd"), run.signal("ur_cmd")  # what the estimator was given (the commands)
    t = run.t
    with open(out / "commands.csv", "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(STREAMS["commands"]) + "\n")
        for i in range(len(t)):
            fh.write(f"{float(t[i])!r},{float(ul[i])!r},{float(ur[i])!r}\n")
    # the PWM duty the drivers applied over each period (after the dead band, as the motor model
    # got it): DC motors only; an ideal torque source has no duty
    if getattr(cfg, "motor", None) is None:
        (out / "duty.csv").unlink(missing_ok=True)  # none from an earlier log in this directory
    else:
        dl, dr = run.signal("duty_l"), run.signal("duty_r")
        with open(out / "duty.csv", "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(STREAMS["duty"]) + "\n")
            for i in range(len(t)):
                fh.write(f"{float(t[i])!r},{float(dl[i])!r},{float(dr[i])!r}\n")
    # the truth, with the state truth the EKF's NEES needs (wheel angles, the gyro's bias in each
    # sample: empty where none was taken) when the run recorded it
    st = run.sensor_truth or {}
    state = run.gyro_bias is not None and all(k in st for k in ("gyro_scale", "accel_scale", "encoder_phase"))
    with open(out / "truth.csv", "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(STREAMS["truth"] + (TRUTH_STATE if state else ())) + "\n")
        cols = [run.signal(n) for n in STREAMS["truth"][1:]]
        wheels = [run.signal("psi_l"), run.signal("psi_r")] if state else []
        bias = run.gyro_bias
        for i in range(len(t)):
            row = [repr(float(t[i]))] + [repr(float(c[i])) for c in cols] + [repr(float(w[i])) for w in wheels]
            if state:
                row += [repr(float(v)) for v in bias[i]] if np.isfinite(bias[i]).all() else ["", "", ""]
            fh.write(",".join(row) + "\n")
    p = run.model_params
    lines = [f'format = "{FORMAT}"', f"version = {VERSION}", f"control_rate = {float(cfg.control_rate)!r}",
             f"wheel_radius = {float(p.r)!r}", f"track = {float(2.0 * p.b)!r}",
             f"encoder_counts = {int(sensors.encoders.counts_per_rev)}",
             f"imu_position = [{', '.join(repr(float(v)) for v in sensors.imu.position)}]",
             f"initial_heading = {float(heading)!r}"]
    if scenario is not None:
        # a sweep's sample (twin.sweep.sampling) is its scenario's file and --set items with other
        # draws (plant, tilt, pushes, seed), never other sensors or motors: name that file, say the sample
        base, _, sample = scenario.source.partition(", sweep sample ")
        src = base.split(" with --set ")[0]
        if sample:
            source = f"{source}, sweep sample {sample}"
        name = src[len("built-in scenario "):] if src.startswith("built-in scenario ") else None
        if name is None:  # a file of one's own: copied beside the log, so the log stands alone
            (out / "scenario.toml").write_bytes(Path(src).read_bytes())
            name = "scenario.toml"
        lines += [f"scenario = {_toml_str(name)}",
                  "set = [" + ", ".join(_toml_str(o) for o in scenario.overrides) + "]"]
    robot = [f"{k} = {float(getattr(p, k))!r}" for k in p.__dataclass_fields__ if k not in ("r", "b", "n_xb")]
    lines += [f"source = {_toml_str(source)}", "", "[robot]", *robot, f"n_xb = {float(p.n_xb)!r}", "", "[commands]",
              'unit = "N·m"', ""]
    if state:  # the sensors' drawn constants and the plant's radius: the rest of the EKF's state truth
        vec = lambda v: "[" + ", ".join(repr(float(e)) for e in v) + "]"  # noqa: E731
        lines += ["[truth]", f"gyro_scale = {vec(st['gyro_scale'])}", f"accel_scale = {vec(st['accel_scale'])}",
                  f"encoder_phase = {vec(st['encoder_phase'])}", f"wheel_radius = {float(cfg.params.r)!r}", ""]
    (out / "log.toml").write_text("\n".join(lines), encoding="utf-8")
    return out


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


__all__ = ["COMMAND_UNITS", "FORMAT", "STREAMS", "SensorLog", "TIME_TOLERANCE", "TRUTH_KEYS", "TRUTH_STATE",
           "VERSION", "read_log", "write_log"]
