"""The sensor-log format (versions 1 and 2): what a robot recorded, as an outsider writes it.

Version 2 (what :func:`write_log` writes; the reference is docs/reference/sensor-log.md) says
in log.toml every figure the estimators are built with: ``[imu]`` (sampling "mean" or "point",
rate Hz, latency s, position m, orientation rad or orientation_matrix, a preset) with
``[imu.gyro]`` and ``[imu.accel]`` (noise density or σ per sample, bias random walk or
instability, turn-on bias, scale-factor error, full scale, bits or LSB), ``[encoders]``
(counts per revolution, on the wheel or the motor with its gear ratio, latency s),
``[commands]`` (unit "N·m", "duty" or "V"; semantics "held" or "sampled"), ``[motor]`` (kind
"dc" with twin.actuators.DCMotorParams figures, or "ideal"), ``[robot]`` (twin.params keys,
SI), ``[truth]`` and ``[streams.NAME]`` (a stream of one's own: its file, its columns with their
units). A stream named after a sensor type of :data:`twin.sensors.types.SENSOR_TYPES` (the motor
current: ``[streams.motor_current]``, motor_current.csv, columns t, left, right in s, A, A) is
that sensor's channel: its columns and units must be the channel's, its figures are in
``[sensors.motor_current]`` (noise, offset, gain_error, resolution, full_scale in A or 1, rate Hz,
latency s: :data:`twin.sensors.motor_current.KEYS`; the keys left out are the type's defaults, and
``[sensors.NAME]`` alone declares the stream NAME.csv with the channel's columns), and the replay
hands it to the estimators (``Measurement.extra``, ``meas["motor_current"]``) and calibration
uses it (:attr:`SensorLog.channels`). What it leaves out that has a default is named in :attr:`SensorLog.format_info`. The
IMU's readings are turned into body axes as they are read (:attr:`SensorLog.imu_rotation`).
Version 1, below, is still read: its figures come from a scenario (default paper-exp1), and
:attr:`SensorLog.format_info` spells out what was assumed.

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

``log.toml``, version 1::

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
    encoder_phase = [0.31, 0.77]         # counts, left right: φ in count = floor((q − q(t_0)) / Δ + φ)
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
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from twin.errors import TwinError, shown
from twin.inputs import inside, read_text, toml_loads
from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams
from twin.logs.bounds import MAX_INSTANTS, MAX_MANIFEST_BYTES, MAX_STREAMS
from twin.logs.streams import read_stream
from twin.params import NOMINAL, PARAMETER_DOCS, RobotParams
from twin.protocols import Targets
from twin.registry import BuildContext
from twin.sensors import SensorConfig
from twin.sensors.specs import IMU_PRESETS, EncoderSpec, ImuSpec, preset_name
from twin.rotations import mounting_matrix
from twin.sensors.types import SENSOR_TYPES, extra_types, key_list

FORMAT = "mtwip-sensor-log"
VERSION = 2  # the version write_log writes
VERSIONS = (1, 2)  # the versions read_log reads
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
              "encoder_phase": (2, "counts, left, right: φ in count = floor((q − q(t_0)) / Δ + φ), q the wheel's "
                                   "angle relative to the body, Δ one count in rad, t_0 the replay's first instant"),
              "wheel_radius": (None, "m: the true wheel radius")}
REQUIRED = ("imu", "encoders", "commands")
UNITS = {"time": "s", "gyro": "rad/s", "accel": "m/s^2", "encoders": "counts"}
COMMAND_UNITS = ("N·m", "duty")  # version 1
_KEYS = {"format", "version", "control_rate", "wheel_radius", "track", "encoder_counts", "imu_position",
         "initial_heading", "scenario", "set", "robot", "commands", "units", "source", "expect", "truth", "motor"}

# ---- version 2: every figure in log.toml (docs/reference/sensor-log.md) -------------------------------
# top-level keys of a version-2 manifest; the tables below
_KEYS_V2 = {"format", "version", "control_rate", "wheel_radius", "track", "initial_heading", "scenario", "set",
            "source", "expect", "imu", "encoders", "commands", "motor", "robot", "truth", "units", "streams", "sensors"}
SAMPLINGS = ("mean", "point")
SEMANTICS = ("held", "sampled")
COMMAND_UNITS_V2 = ("N·m", "duty", "V")
ENCODER_MOUNTS = ("wheel", "motor")
MOTOR_KINDS = ("dc", "ideal")
# key -> (unit, meaning): what each table of a version-2 manifest holds (the docs and the messages list these)
IMU_KEYS = {
    "sampling": ("", '"mean": each row the mean over the interval since the previous sample (1/rate), '
                     '"point": the value at one instant'),
    "rate": ("Hz", "the IMU's sample rate (the control rate divided by a whole number)"),
    "latency": ("s", "from the measured instant (a mean's interval end) to the row's t, >= 0"),
    "position": ("m", "[x, y, z] of the sensing point in body axes from the axle midpoint"),
    "orientation": ("rad", "[roll, pitch, yaw]: the IMU's axes are the body's turned by yaw about z, then pitch "
                           "about the new y, then roll about the newest x (v_body = Rz Ry Rx v_imu)"),
    "orientation_matrix": ("1", "3 rows: C with v_body = C v_imu (its columns are the IMU's axes in body axes); "
                                "instead of orientation"),
    "preset": ("", "the part whose figures stand in for the ones [imu.gyro] and [imu.accel] leave out: "
                   "mpu6050 (default), icm42688p, bmi088"),
    "gyro": ("", "table: the gyro's figures (rad/s)"),
    "accel": ("", "table: the accelerometer's figures (m/s²)"),
}
# U: rad/s for the gyro, m/s² for the accelerometer
TRIAD_KEYS = {
    "noise_density": ("U/√Hz", "white noise density (per-sample σ = noise_density·√rate)"),
    "sigma": ("U", "white noise σ of one sample at the IMU's rate (instead of noise_density)"),
    "bias_random_walk": ("U/√s", "bias random walk K (the bias moves K·√Δt a sample)"),
    "bias_correlation_time": ("s", "τ of a first-order Gauss–Markov bias (absent: a random walk)"),
    "bias_instability": ("U", "the Allan deviation's minimum; with bias_correlation_time, instead of "
                              "bias_random_walk: K = bias_instability / 0.6174 · √(2/τ)"),
    "turn_on_bias": ("U", "σ of the bias left at power-up"),
    "scale_factor_error": ("1", "σ of each axis's scale-factor error"),
    "full_scale": ("U", "the range ±full_scale: a reading there is clipped"),
    "bits": ("1", "ADC bits: one step is full_scale / 2^(bits−1)"),
    "lsb": ("U", "one ADC step (instead of bits; full_scale / lsb a power of two within 2 %)"),
}
TRIAD_UNITS = {"gyro": "rad/s", "accel": "m/s²"}
ENCODER_KEYS = {
    "counts_per_rev": ("counts", "counts per revolution of the shaft the encoder is on (×4 decoding included)"),
    "on": ("", '"wheel" or "motor" (then gear_ratio)'),
    "gear_ratio": ("1", "motor revolutions per wheel revolution (on = \"motor\" only)"),
    "latency": ("s", "from the measured instant to the row's t, >= 0"),
}
COMMAND_KEYS = {
    "unit": ("", '"N·m" (wheel torque), "duty" (PWM duty in [-1, 1]) or "V" (volts; the supply is '
                 '[motor] supply_voltage)'),
    "semantics": ("", '"held" (applied from its t to the next row) or "sampled" (the value at that instant; '
                      'a control period gets the mean of the samples joined by straight lines over it)'),
}
STREAM_KEYS = {
    "file": ("", "the stream's CSV file, a name beside log.toml (default NAME.csv)"),
    "columns": ("", "table: column name -> unit, in the file's order, t (unit \"s\") first"),
    "latency": ("s", "from the measured instant to the row's t (optional)"),
    "description": ("", "free text (optional)"),
}
ALLAN_PEAK = 0.6174  # the peak Allan deviation of a first-order Gauss–Markov process over its steady σ (τ ≈ 1.89 T)
ROTATION_TOLERANCE = 1e-6  # |CᵀC − I| and |det C − 1| for an orientation_matrix
_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyz0123456789_")


@dataclass(frozen=True)
class Stream:
    """A stream log.toml declares beyond the format's own (version 2, ``[streams.NAME]``): a
    motor current, a second IMU. ``t`` (n,) s; ``values`` (n, c) in ``units`` (NaN where a field
    was empty); ``columns`` and ``units`` the c columns after ``t``; ``latency`` s or None."""

    name: str
    file: str
    columns: tuple
    units: tuple
    t: np.ndarray
    values: np.ndarray
    latency: float | None = None
    description: str = ""


@dataclass(frozen=True)
class SensorLog:
    """A log as read (:func:`read_log`): its manifest's figures and the streams as arrays.

    ``imu_t`` (n,) s with ``gyro`` (n, 3) rad/s and ``accel`` (n, 3) m/s² in body axes (a
    version-2 log's IMU orientation applied, :attr:`imu_rotation`), NaN rows where a
    row held none; ``encoders_t`` (m,) s with ``counts`` (m, 2) int64 (``has_counts`` (m,)
    where a row held them); ``commands_t`` (k,) s with ``commands`` (k, 2) N·m (duty and volts
    converted; :attr:`command_semantics` says whether each is held or sampled); ``truth_t`` and
    ``truth`` (j, 6) [θ, θ̇, ψ, ψ̇, α, α̇] or None;
    ``truth_state`` (j, 5) [ψ_l, ψ_r rad, gyro bias x, y, z rad/s] where truth.csv has those
    columns, else None, and ``truth_constants`` the manifest's ``[truth]`` table (a dict of
    floats and tuples), else None; ``duty_t`` (d,) s and ``duty`` (d, 2) [left, right] the
    PWM duty the drivers applied (dimensionless, [-1, 1], after the dead band; see the module
    docstring) where the log has duty.csv, else None; ``streams`` the other streams log.toml
    declares (version 2, :class:`Stream`), read and checked, used by no estimator;
    ``format_info`` the format's version and what the reader assumed where the log is silent
    (``{"version", "assumed", "text"}``); ``notes`` what could not be applied as the log says."""

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
    version: int = 1
    sampling: str = "mean"  # the IMU's rows: "mean" over the interval since the previous sample, or "point"
    command_unit: str = "N·m"  # as commands.csv holds them ("N·m", "duty", "V"); :attr:`commands` is in N·m
    command_semantics: str = "held"  # "held" from each row's t, or "sampled" at it
    imu_rotation: tuple | None = None  # C (3 rows), v_body = C v_imu, applied to gyro and accel; None: identity
    streams: dict = field(default_factory=dict)  # the other streams log.toml declares: name -> Stream
    format_info: dict = field(default_factory=dict)  # what the format said and what was assumed (the replay's)
    notes: tuple = ()  # what the reader could not apply as the log says, one line each

    @property
    def channels(self) -> dict:
        """The sensor channels beyond the IMU and encoders this log holds (:mod:`twin.sensors.types`):
        channel name -> :class:`Stream` (``t`` s, ``values`` (n, c) in the channel's unit, NaN where
        a row held none), e.g. ``"motor_current"`` (left, right in A); {} for none."""
        names = {c.name for t in extra_types() for c in t.channels}
        return {n: st for n, st in self.streams.items() if n in names}

    @property
    def counts_per_rev(self) -> int:
        """Encoder counts per wheel revolution (a motor's counts times the gear ratio)."""
        return int(self.sensors.encoders.counts_per_rev)

    @property
    def duration(self) -> float:
        """s from the first command to the last."""
        return float(self.commands_t[-1] - self.commands_t[0])

    def context(self):
        """The :class:`twin.registry.BuildContext` an estimator is built with for this log."""
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
        if self.command_unit not in ("duty", "V") or self.motor is None:
            return self.motor
        if not self.motor.back_emf_compensation and self.motor.current_limit is None:
            return self.motor
        return replace(self.motor, back_emf_compensation=False, current_limit=None)


# ---- reading ---------------------------------------------------------------------------------------

def rows_times(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``v @ m`` for (n, 3) rows and a 3 × 3 ``m``, as three elementwise products summed in a fixed
    order: a matrix product goes to the BLAS, whose kernels (and threads) round differently on
    different CPUs, and a replay must give the same bits on every machine."""
    return np.column_stack([v[:, 0] * m[0, j] + v[:, 1] * m[1, j] + v[:, 2] * m[2, j] for j in range(3)])

def read_log(path) -> SensorLog:
    """The log in directory ``path``, checked (see the module docstring; version 2:
    docs/reference/sensor-log.md)."""
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
                        f"control_rate, wheel_radius, track, encoder_counts and imu_position (version 1; version 2: "
                        f"docs/reference/sensor-log.md)") from None
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
    version = m.get("version")
    if isinstance(version, bool) or version not in VERSIONS:
        raise TwinError(f"{where}: version: {shown(version)} is not known here; allowed: "
                        f"{', '.join(map(str, VERSIONS))} (a newer twin may read it)")
    h = _header_v1(root, m, where) if int(version) == 1 else _header_v2(root, m, where)
    rate, motor, cunit = h.rate, h.motor, h.command_unit

    imu = _stream(root, "imu", required=True, file=h.files.get("imu"))
    enc = _stream(root, "encoders", required=True, integers=True, file=h.files.get("encoders"))
    cmd = _stream(root, "commands", required=True, need_all=True, file=h.files.get("commands"))
    tru = _stream(root, "truth", required=False, file=h.files.get("truth"))
    duty = _stream(root, "duty", required=False, need_all=True, file=h.files.get("duty"))
    constants = _truth_table(m.get("truth"), where) if "truth" in m else None
    t_imu, gyro, accel = imu[:, 0], imu[:, 1:4], imu[:, 4:7]
    if h.rotation is not None:  # the IMU's axes into the body's: v_body = C v_imu (row vectors: V C^T)
        c_t = np.array(h.rotation, dtype=float).T
        gyro, accel = rows_times(gyro, c_t), rows_times(accel, c_t)
    imu_path = root / (h.files.get("imu") or "imu.csv")
    _check_gravity(imu_path, accel, t_imu, "" if h.version == 1 else " after [imu] orientation")
    ecount = enc[:, 1:3]
    has = np.isfinite(ecount).all(axis=1)
    counts_i = np.zeros(ecount.shape, dtype=np.int64)
    counts_i[has] = ecount[has].astype(np.int64)
    commands = cmd[:, 1:3]
    cpath = root / (h.files.get("commands") or "commands.csv")
    if cunit == "duty":
        if np.any(np.abs(commands) > 1.0):
            row = int(np.argmax((np.abs(commands) > 1.0).any(axis=1)))
            raise TwinError(f"{cpath}: row {row + 2}: a PWM duty outside [-1, 1]")
        commands = commands * motor.stall_torque
    elif cunit == "V":  # volts: the duty V / supply, then as a duty
        supply = motor.supply_voltage
        if np.any(np.abs(commands) > supply):
            row = int(np.argmax((np.abs(commands) > supply).any(axis=1)))
            raise TwinError(f"{cpath}: row {row + 2}: a voltage beyond the supply's ±{supply:g} V; allowed: |V| up to "
                            f"[motor] supply_voltage")
        commands = commands / supply * motor.stall_torque
    if len(cmd) < 2:
        raise TwinError(f"{cpath}: {len(cmd)} row(s); a log needs at least 2 control instants")
    _check_instants(cpath, cmd[:, 0], rate)
    if duty is not None:
        _check_duty(root / (h.files.get("duty") or "duty.csv"), duty, cmd[:, 0])
    extra = {name: _extra_stream(root, where, name, decl) for name, decl in h.extra.items()}
    return SensorLog(root, m, rate, h.model, h.sensors, motor, h.heading, t_imu, gyro, accel, enc[:, 0], counts_i,
                     has, cmd[:, 0], commands, None if tru is None else tru[:, 0],
                     None if tru is None else tru[:, 1:7], h.scenario,
                     None if tru is None or tru.shape[1] == 7 else tru[:, 7:], constants,
                     None if duty is None else duty[:, 0], None if duty is None else duty[:, 1:3],
                     version=h.version, sampling=h.sampling, command_unit=cunit, command_semantics=h.semantics,
                     imu_rotation=h.rotation, streams=extra, format_info=h.info, notes=tuple(h.notes))


@dataclass
class _Header:
    """What a manifest says (either version), before the streams are read."""

    version: int
    rate: float
    heading: float
    model: object
    sensors: object
    motor: object
    scenario: object
    command_unit: str
    semantics: str = "held"
    sampling: str = "mean"
    rotation: tuple | None = None
    files: dict = field(default_factory=dict)  # a format stream -> its file name, where log.toml renames it
    extra: dict = field(default_factory=dict)  # the other declared streams: name -> their declaration
    info: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def _header_v1(root: Path, m: dict, where: str) -> _Header:
    """A version-1 manifest: the sensors' and motors' figures from its scenario (default
    paper-exp1), which :func:`_v1_assumed` spells out for the replay to say."""
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
    _check_units(units, cunit, where)

    scenario = _scenario(root, m, where, counts, pos)
    model, _ = _robot(m.get("robot", {}), radius, track, where)
    sensors = scenario.believed_sensor_config()
    if sensors is None:
        raise TwinError(f"{where}: scenario: its sensors.sensing is \"ideal\"; a log holds readings: the scenario "
                        f"must have simulated sensors")
    motor = scenario.twin_config().motor
    if "motor" in m:  # the robot's motors and drivers: twin.actuators.DCMotorParams keys, SI
        motor, _ = _dc_motor(m["motor"], motor, where)  # (version 1: the scenario's motor under the figures)
    if cunit == "duty" and motor is None:
        raise TwinError(f"{where}: commands.unit = \"duty\" needs the motor's figures (the scenario's "
                        f"plant.motor = \"dc\")")
    info = _v1_assumed(m, sensors, motor)
    return _Header(1, rate, heading, model, sensors, motor, scenario, cunit, info=info)


def _check_units(units: dict, cunit: str, where: str) -> None:
    """The optional ``[units]`` table: if given, exactly the format's units."""
    for k, v in units.items():
        want = cunit if k == "commands" else UNITS.get(k)
        if want is None:
            raise TwinError(f"{where}: units.{k}: unknown stream quantity; allowed: "
                            f"{', '.join(list(UNITS) + ['commands'])}")
        if v != want:
            raise TwinError(f"{where}: units.{k}: {shown(v)}; allowed: {want!r} (the format's units are SI: convert "
                            f"when writing the log)")


def _keys_text(keys: dict, unit_for: str = "") -> str:
    """``key (unit)`` of each key of a table's documentation, for a message listing what is allowed."""
    out = []
    for k, (unit, _) in keys.items():
        u = unit.replace("U", unit_for) if unit_for else unit
        out.append(f"{k} ({u})" if u else k)
    return ", ".join(out)


def robot_keys() -> dict:
    """The ``[robot]`` keys: :data:`twin.params.PARAMETER_DOCS` but r and b (wheel_radius, track)."""
    return {k: v for k, v in PARAMETER_DOCS.items() if k not in ("r", "b")}


def motor_keys() -> dict:
    """The ``[motor]`` keys of a DC motor and its driver (:class:`twin.actuators.DCMotorParams`),
    as seen at the wheel: key -> (unit, meaning)."""
    return {"supply_voltage": ("V", "the driver's supply"),
            "stall_torque": ("N·m", "at the wheel, at the supply voltage"),
            "no_load_speed": ("rad/s", "the wheel's, relative to the body, at the supply voltage"),
            "current_limit": ("A", "the driver's current limit (absent: none but the stall current)"),
            "pwm_bits": ("1", "duty resolution: 2^bits − 1 steps per direction"),
            "dead_band": ("1", "a |duty| below this gives no voltage"),
            "inductance": ("H", "0 leaves out the electrical lag"),
            "back_emf_compensation": ("", "true: the driver adds the back-EMF at the measured speed to a "
                                          "torque command")}


def _robot(robot, radius: float, track: float, where: str):
    """(the model the estimators assume, the keys not given: Table III's) from ``[robot]``."""
    keys = robot_keys()
    listing = ", ".join(f"{k} ({u})" for k, (u, _) in keys.items())
    if not isinstance(robot, dict):
        raise TwinError(f"{where}: robot must be a table of twin.params.RobotParams keys ({listing}), got "
                        f"{shown(robot)}")
    for k in ("r", "b"):
        if k in robot:
            raise TwinError(f"{where}: robot.{k}: give it as {'wheel_radius' if k == 'r' else 'track (= 2 b)'}")
    unknown = sorted(set(robot) - set(keys))
    if unknown:
        raise TwinError(f"{where}: robot.{unknown[0]}: unknown key; allowed keys: {listing}")
    try:
        fields = {**{k: getattr(NOMINAL, k) for k in NOMINAL.__dataclass_fields__ if k != "n_xb"}, **robot,
                  "r": radius, "b": track / 2.0}
        if "n_xb" in robot:
            fields["n_xb"] = robot["n_xb"]
        model = RobotParams(**fields)
    except TypeError as exc:
        raise TwinError(f"{where}: robot: {' '.join(str(exc).split())}; allowed keys: {listing}") from None
    except TwinError as exc:
        raise TwinError(f"{where}: robot: {exc}") from None
    return model, [k for k in keys if k not in robot]


def _dc_motor(table, base, where: str, skip: tuple = ()):
    """(the DC motor of ``[motor]``'s figures over ``base``'s (default the twin's default), the keys
    not given); the keys of ``skip`` are not figures."""
    keys = motor_keys()
    listing = _keys_text(keys)
    if not isinstance(table, dict):
        raise TwinError(f"{where}: motor must be a table of twin.actuators.DCMotorParams keys ({listing}), got "
                        f"{shown(table)}")
    figures = {k: v for k, v in table.items() if k not in skip}
    try:
        motor = DCMotorParams(**{**{k: getattr(base or DEFAULT_MOTOR, k) for k in DCMotorParams.__dataclass_fields__},
                                 **figures})
    except TypeError:
        bad = sorted(set(figures) - set(DCMotorParams.__dataclass_fields__))
        raise TwinError(f"{where}: motor.{bad[0] if bad else '?'}: unknown; allowed: {listing}") from None
    except TwinError as exc:
        raise TwinError(f"{where}: motor: {exc}") from None
    return motor, [k for k in keys if k not in figures and k != "current_limit"]


def _v1_assumed(m: dict, sensors, motor) -> dict:
    """What a version-1 log leaves unsaid and the reader took from its scenario: ``{"version": 1,
    "assumed": {...}, "text": one line}``."""
    imu, enc = sensors.imu, sensors.encoders
    name = m.get("scenario", "paper-exp1")
    items = m.get("set", [])
    source = f"scenario {name}" + (f" with {', '.join(items)}" if items else "")
    preset = preset_name(imu.gyro, imu.accel)

    def triad(t):
        return {"noise_density": t.noise_density, "bias_random_walk": t.bias_random_walk,
                "bias_correlation_time_s": t.bias_correlation_time, "turn_on_bias": t.turn_on_bias,
                "scale_factor_error": t.scale_factor_error, "full_scale": t.full_scale, "bits": t.bits}

    assumed = {"from": source,
               "imu": {"sampling": "mean", "rate_hz": imu.rate, "latency_s": imu.latency,
                       "orientation": "the body's axes", "preset": preset, "gyro": triad(imu.gyro),
                       "accel": triad(imu.accel)},
               "encoders": {"on": "wheel", "latency_s": enc.latency},
               "commands": {"semantics": "held"},
               "motor": None if motor is None else {k: getattr(motor, k) for k in motor_keys()}}
    noise = f"{preset} noise figures" if preset else "the scenario's noise figures"
    motors = "ideal torque sources" if motor is None else (
        f"DC motors ({motor.supply_voltage:g} V, {motor.stall_torque:g} N·m stall, {motor.no_load_speed:g} rad/s "
        f"no-load)")
    text = (f"log format version 1, which leaves unsaid what version 2 states; assumed from {source}: IMU rows are "
            f"means over {1e3 / imu.rate:g} ms ({imu.rate:g} Hz), {imu.latency * 1e3:g} ms late, in the body's axes, "
            f"{noise}; encoders on the wheels, {enc.latency * 1e3:g} ms late; commands held; {motors}")
    return {"version": 1, "assumed": assumed, "text": text}


# ---- version 2 ---------------------------------------------------------------------------------------
def _table(m: dict, key: str, where: str, keys: dict, required: bool = True, unit_for: str = "") -> dict:
    """Table ``key`` of ``m`` (a dict), with no key but ``keys``' (a one-line error naming the first
    other one and listing ``keys`` with their units)."""
    v = m.get(key)
    if v is None and not required:
        return {}
    if not isinstance(v, dict):
        raise TwinError(f"{where}: {key}: {'missing' if v is None else shown(v)}; allowed: a table of "
                        f"{_keys_text(keys, unit_for)} (docs/reference/sensor-log.md)")
    unknown = [k for k in v if k not in keys]
    if unknown:
        raise TwinError(f"{where}: {key}.{unknown[0]}: unknown key; allowed: {_keys_text(keys, unit_for)}")
    return v


def _choice(t: dict, key: str, where: str, choices: tuple, what: str) -> str:
    """``t[key]``, one of ``choices`` (``key`` as the message names it: "imu.sampling"), else one line."""
    v = t.get(key.rsplit(".", 1)[-1])
    if v not in choices or not isinstance(v, str):
        raise TwinError(f"{where}: {key}: {'missing' if v is None else shown(v)}; allowed: "
                        f"{' or '.join(repr(c).replace(chr(39), chr(34)) for c in choices)} ({what})")
    return v


def _whole_periods(latency: float, rate: float, key: str, notes: list) -> float:
    """``latency`` (s) as the estimators take it: a whole number of control periods (rounded, with
    a note, where it is not one)."""
    k = latency * rate
    if abs(k - round(k)) <= 1e-9 * max(1.0, k):
        return latency
    taken = round(k) / rate
    notes.append(f"{key} = {latency:g} s is not a whole number of control periods ({1.0 / rate:g} s): the estimators "
                 f"take {round(k)} ({taken:g} s)")
    return taken


def _header_v2(root: Path, m: dict, where: str) -> _Header:
    """A version-2 manifest: every figure the estimators are built with is log.toml's (the keys
    it leaves out that have a default are listed in the header's ``info``)."""
    unknown = sorted(set(m) - _KEYS_V2)
    if unknown:
        raise TwinError(f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_KEYS_V2))}")
    rate = _number(m, "control_rate", where, 0.0, 1e5, "Hz", lo_open=True)
    radius = _number(m, "wheel_radius", where, 0.0, 1.0, "m", lo_open=True)
    track = _number(m, "track", where, 0.0, 5.0, "m", lo_open=True)
    heading = _number(m, "initial_heading", where, -1e3, 1e3, "rad", default=0.0)
    notes: list = []
    assumed: dict = {}
    imu, sampling, rotation = _imu_v2(m, where, rate, notes, assumed)
    encoders = _encoders_v2(m, where, rate, notes)
    c = _table(m, "commands", where, COMMAND_KEYS)
    cunit = _choice(c, "commands.unit", where, COMMAND_UNITS_V2, "commands.csv's ul, ur")
    semantics = _choice(c, "commands.semantics", where, SEMANTICS, "held from the row's t, or sampled at it")
    mt = _table(m, "motor", where, {"kind": ("", '"dc" or "ideal" (torque sources)'), **motor_keys()})
    kind = _choice(mt, "motor.kind", where, MOTOR_KINDS, "DC motors with drivers, or ideal torque sources")
    if kind == "ideal":
        extra = [k for k in mt if k != "kind"]
        if extra:
            raise TwinError(f"{where}: motor.{extra[0]}: an ideal torque source has no figures; allowed: kind = "
                            f"\"dc\" with the figures, or kind = \"ideal\" alone")
        motor = None
    else:
        motor, left = _dc_motor(mt, None, where, skip=("kind",))
        if left:
            assumed["motor"] = left
    if cunit in ("duty", "V") and motor is None:
        raise TwinError(f"{where}: commands.unit = \"{cunit}\" needs DC motors' figures; allowed: [motor] kind = "
                        f"\"dc\" (with supply_voltage and stall_torque), or unit = \"N·m\"")
    if cunit == "V" and "supply_voltage" not in mt:
        raise TwinError(f"{where}: motor.supply_voltage: missing; commands in volts need it (duty = V / "
                        f"supply_voltage); allowed: a number in (0, 10000] V")
    model, left = _robot(m.get("robot", {}), radius, track, where)
    if left:
        assumed["robot"] = left
    units = m.get("units", {})
    if not isinstance(units, dict):
        raise TwinError(f"{where}: units must be a table, got {shown(units)}")
    _check_units(units, cunit, where)
    files, extra = _declared_streams(m.get("streams"), where, cunit)
    specs = _sensor_channels(m, extra, where, rate, notes, assumed)
    scenario = _scenario_v2(root, m, where)
    sensors = SensorConfig(imu=imu, encoders=encoders, extra=specs)
    if assumed:
        parts = [f"{k} {', '.join(v)}" for k, v in assumed.items()]
        whose = {"robot": "Table III", "motor": "twin.actuators.DCMotorParams",
                 **{f"sensors.{t.name}": f"twin.sensors.types.SENSOR_TYPES[{t.name!r}]" for t in extra_types()}}
        text = (f"log format version 2; not in log.toml, so assumed: "
                + "; ".join(f"{p} ({whose.get(k, imu_preset_of(m))}'s)" for p, k in zip(parts, assumed)))
    else:
        text = "log format version 2: every figure the estimators use is in log.toml"
    info = {"version": 2, "assumed": assumed, "text": text}
    return _Header(2, rate, heading, model, sensors, motor, scenario, cunit, semantics, sampling, rotation, files,
                   extra, info, notes)


def _sensor_channels(m: dict, extra: dict, where: str, rate: float, notes: list, assumed: dict) -> tuple:
    """The specs of the sensor channels a version-2 manifest holds beyond the IMU and encoders
    (see the module docstring): ``[sensors.NAME]`` figures for a declared ``[streams.NAME]`` whose
    NAME is a sensor type (its columns and units checked against the channel's), or alone (then
    the stream NAME.csv with the channel's columns is declared here, in ``extra``)."""
    table = m.get("sensors", {})
    types = {t.name: t for t in extra_types()}
    listing = ", ".join(f"[sensors.{n}]" for n in types)
    if not isinstance(table, dict):
        raise TwinError(f"{where}: sensors: {shown(table)}; allowed: tables {listing} (a sensor channel's figures)")
    for name in table:
        if name not in types:
            core = " (the IMU's and encoders' figures are [imu] and [encoders])" if name in SENSOR_TYPES else ""
            raise TwinError(f"{where}: sensors.{name}: not a sensor type{core}; allowed: {listing}")
    specs = []
    for name, t in types.items():
        if name not in table and name not in extra:
            continue
        c = t.channels[0]
        if name in extra:  # the declared stream: the channel's columns, in its unit
            d = extra[name]
            units = tuple(_SAME_UNIT.get(u, u) for u in d["units"])
            if d["columns"] != c.columns or any(u != c.unit for u in units):
                cols = ", ".join(f"{k} = \"{c.unit}\"" for k in c.columns)
                raise TwinError(f"{where}: streams.{name}.columns: {', '.join(d['columns'])} in "
                                f"{', '.join(d['units'])}; allowed: {{ t = \"s\", {cols} }} (the {name} channel's "
                                f"columns, SI)")
        else:  # [sensors.NAME] alone: the stream NAME.csv with the channel's columns
            extra[name] = {"file": f"{name}.csv", "columns": c.columns, "units": (c.unit,) * len(c.columns),
                           "latency": None, "description": t.doc}
        figures = dict(table.get(name) or {})
        if not isinstance(table.get(name, {}), dict):
            raise TwinError(f"{where}: sensors.{name}: {shown(table[name])}; allowed: a table of {key_list(t)}")
        lat = figures.get("latency", extra[name]["latency"])
        if lat is not None and "latency" not in figures:
            figures["latency"] = lat
        spec = t.build(figures, where)
        taken = _whole_periods(spec.latency, rate, f"sensors.{name}.latency", notes)
        if taken != spec.latency:
            spec = replace(spec, latency=taken)
        try:  # (each row arrives at its t; the rate says how often the robot sampled)
            spec.steps(rate)
        except TwinError as exc:
            raise TwinError(f"{where}: {exc}") from None
        left = [k for k in t.keys if k not in figures and k != "rate"]
        if left:
            assumed[f"sensors.{name}"] = left
        specs.append(spec)
    return tuple(specs)


def imu_preset_of(m: dict) -> str:
    """The preset a version-2 manifest's ``[imu]`` names for the figures it leaves out (default mpu6050)."""
    imu = m.get("imu") if isinstance(m.get("imu"), dict) else {}
    return imu.get("preset", "mpu6050")


def _imu_v2(m: dict, where: str, rate: float, notes: list, assumed: dict):
    """(ImuSpec, sampling, rotation C or None) of ``[imu]``."""
    t = _table(m, "imu", where, IMU_KEYS)
    sampling = _choice(t, "imu.sampling", where, SAMPLINGS,
                       "mean over the interval since the previous sample, or the value at one instant")
    r = t.get("rate")
    if not (_is_number(r) and 0.0 < r <= 1e5):
        raise TwinError(f"{where}: imu.rate: {'missing' if r is None else shown(r)}; allowed: a number in (0, 1e5] Hz "
                        f"(the IMU's sample rate)")
    ratio = rate / r
    if r > rate * (1.0 + 1e-9) or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise TwinError(f"{where}: imu.rate: {r:g} Hz; allowed: the control rate ({rate:g} Hz) divided by a whole "
                        f"number ({', '.join(f'{rate / k:.6g}' for k in (1, 2, 3, 4))} Hz, ...)")
    lat = t.get("latency")
    if not (_is_number(lat) and 0.0 <= lat <= 1.0):
        raise TwinError(f"{where}: imu.latency: {'missing' if lat is None else shown(lat)}; allowed: a number in "
                        f"[0, 1] s (from the measured instant to the row's t)")
    lat = _whole_periods(float(lat), rate, "imu.latency", notes)
    pos = t.get("position")
    if not (isinstance(pos, list) and len(pos) == 3 and all(_is_number(v) and abs(v) <= 1.0 for v in pos)):
        raise TwinError(f"{where}: imu.position: {'missing' if pos is None else shown(pos)}; allowed: [x, y, z] in "
                        f"m, body axes from the axle midpoint, each within ±1 m")
    rotation = _orientation(t, where)
    preset = t.get("preset", "mpu6050")
    if preset not in IMU_PRESETS:
        raise TwinError(f"{where}: imu.preset: {shown(preset)}; allowed: {', '.join(IMU_PRESETS)}")
    triads = []
    for name, base in zip(("gyro", "accel"), IMU_PRESETS[preset]):
        triad, left = _triad(t.get(name), base, where, name, float(r))
        if left:
            assumed[f"imu.{name}"] = left
        triads.append(triad)
    try:
        imu = ImuSpec(gyro=triads[0], accel=triads[1], position=tuple(float(v) for v in pos), rate=float(r),
                      latency=lat)
    except TwinError as exc:
        raise TwinError(f"{where}: imu: {exc}") from None
    return imu, sampling, rotation


def _orientation(t: dict, where: str):
    """The rotation C (3 rows, v_body = C v_imu) of ``[imu]``'s orientation or orientation_matrix;
    None for the identity (the IMU's axes are the body's)."""
    has_a, has_m = "orientation" in t, "orientation_matrix" in t
    if has_a and has_m:
        raise TwinError(f"{where}: imu.orientation and imu.orientation_matrix: both given; allowed: one of them")
    if not has_a and not has_m:
        raise TwinError(f"{where}: imu.orientation: missing; allowed: [roll, pitch, yaw] in rad ([0, 0, 0]: the "
                        f"IMU's axes are the body's), or orientation_matrix")
    if has_a:
        a = t["orientation"]
        bounds = (math.pi, math.pi / 2.0, math.pi)
        if not (isinstance(a, list) and len(a) == 3 and all(_is_number(v) for v in a)
                and all(abs(v) <= b + 1e-12 for v, b in zip(a, bounds))):
            raise TwinError(f"{where}: imu.orientation: {shown(a)}; allowed: [roll, pitch, yaw] in rad (not degrees), "
                            f"roll and yaw within ±π, pitch within ±π/2")
        if all(v == 0 for v in a):
            return None
        return mounting_matrix(*a)
    c = t["orientation_matrix"]
    if not (isinstance(c, list) and len(c) == 3 and all(isinstance(row, list) and len(row) == 3 for row in c)
            and all(_is_number(v) for row in c for v in row)):
        raise TwinError(f"{where}: imu.orientation_matrix: {shown(c)}; allowed: 3 rows of 3 numbers, a rotation C "
                        f"with v_body = C v_imu")
    C = np.array(c, dtype=float)
    off = float(np.abs(C.T @ C - np.eye(3)).max())
    det = float(np.linalg.det(C))
    if off > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise TwinError(f"{where}: imu.orientation_matrix: not a rotation (largest |CᵀC − I| {off:.3g}, det "
                        f"{det:.6g}); allowed: an orthonormal matrix with determinant +1 (within "
                        f"{ROTATION_TOLERANCE:g}), v_body = C v_imu")
    if np.array_equal(C, np.eye(3)):
        return None
    return tuple(tuple(float(v) for v in row) for row in c)


def _triad(table, base, where: str, name: str, rate: float):
    """(TriadSpec, the figures not given: ``base``'s) of ``[imu.gyro]`` or ``[imu.accel]``."""
    key, unit = f"imu.{name}", TRIAD_UNITS[name]
    t = _table({key: table}, key, where, TRIAD_KEYS, required=False, unit_for=unit) if table is not None else {}

    def num(k, lo, hi, lo_open=False):
        v = t[k]
        u = TRIAD_KEYS[k][0].replace("U", unit)
        if not (_is_number(v) and (lo < v if lo_open else lo <= v) and v <= hi):
            raise TwinError(f"{where}: {key}.{k}: {shown(v)}; allowed: a number in {'(' if lo_open else '['}{lo:g}, "
                            f"{hi:g}] {u} ({TRIAD_KEYS[k][1]})")
        return float(v)

    def one_of(a, b):
        if a in t and b in t:
            raise TwinError(f"{where}: {key}.{a} and {key}.{b}: both given; allowed: one of them")

    one_of("noise_density", "sigma")
    one_of("bias_random_walk", "bias_instability")
    one_of("bits", "lsb")
    fig = {}
    if "noise_density" in t:
        fig["noise_density"] = num("noise_density", 0.0, 1e3)
    elif "sigma" in t:
        fig["noise_density"] = num("sigma", 0.0, 1e4) / math.sqrt(rate)
    if "bias_correlation_time" in t:
        fig["bias_correlation_time"] = num("bias_correlation_time", 0.0, 1e7, lo_open=True)
    if "bias_random_walk" in t:
        fig["bias_random_walk"] = num("bias_random_walk", 0.0, 1e3)
    elif "bias_instability" in t:
        if "bias_correlation_time" not in t:
            raise TwinError(f"{where}: {key}.bias_instability needs {key}.bias_correlation_time; allowed: both (a "
                            f"Gauss–Markov bias), or bias_random_walk")
        b = num("bias_instability", 0.0, 1e3)
        fig["bias_random_walk"] = b / ALLAN_PEAK * math.sqrt(2.0 / fig["bias_correlation_time"])
    for k, hi in (("turn_on_bias", 1e3), ("scale_factor_error", 0.5)):
        if k in t:
            fig[k] = num(k, 0.0, hi)
    if "full_scale" in t:
        fig["full_scale"] = num("full_scale", 0.0, 1e6, lo_open=True)
    if "bits" in t:
        b = t["bits"]
        if isinstance(b, bool) or not isinstance(b, int) or not 2 <= b <= 32:
            raise TwinError(f"{where}: {key}.bits: {shown(b)}; allowed: an integer from 2 to 32 (ADC bits)")
        fig["bits"] = b
    elif "lsb" in t:
        lsb = num("lsb", 0.0, 1e6, lo_open=True)
        ratio = fig.get("full_scale", base.full_scale) / lsb
        k = round(math.log2(ratio)) if ratio >= 1.0 else 0
        if not 1 <= k <= 31 or abs(ratio / 2.0 ** k - 1.0) > 0.02:
            raise TwinError(f"{where}: {key}.lsb: {lsb:g} {unit} is not full_scale / 2^(bits−1) for any bits from 2 "
                            f"to 32 (full_scale / lsb = {ratio:.6g}); allowed: an ADC's step (within 2 %), or bits")
        fig["bits"] = k + 1
    left = [k for k in ("noise_density", "bias_random_walk", "turn_on_bias", "scale_factor_error", "full_scale",
                        "bits") if k not in fig]
    try:
        triad = replace(base, bias_correlation_time=fig.pop("bias_correlation_time", None), **fig)
    except TwinError as exc:
        raise TwinError(f"{where}: {key}: {exc}") from None
    problem = triad.range_problem(rate)
    if problem:
        raise TwinError(f"{where}: {key}.full_scale: {problem}")
    return triad, left


def _encoders_v2(m: dict, where: str, rate: float, notes: list):
    """The EncoderSpec of ``[encoders]``: counts per wheel revolution (a motor's times the gear ratio)."""
    t = _table(m, "encoders", where, ENCODER_KEYS)
    counts = t.get("counts_per_rev")
    if isinstance(counts, bool) or not isinstance(counts, int) or not 1 <= counts <= 10_000_000:
        raise TwinError(f"{where}: encoders.counts_per_rev: {'missing' if counts is None else shown(counts)}; "
                        f"allowed: an integer from 1 to 10000000 (counts per revolution of the shaft it is on)")
    on = _choice(t, "encoders.on", where, ENCODER_MOUNTS, "the shaft the encoder is on")
    gear = t.get("gear_ratio")
    if on == "wheel":
        if gear is not None:
            raise TwinError(f"{where}: encoders.gear_ratio: given with on = \"wheel\"; allowed: gear_ratio only with "
                            f"on = \"motor\"")
        wheel = float(counts)
    else:
        if not (_is_number(gear) and 0.0 < gear <= 1e4):
            raise TwinError(f"{where}: encoders.gear_ratio: {'missing' if gear is None else shown(gear)}; allowed: a "
                            f"number in (0, 10000] (motor revolutions per wheel revolution), with on = \"motor\"")
        wheel = counts * float(gear)
    whole = round(wheel)
    if abs(wheel - whole) > 1e-9 * wheel or not 4 <= whole <= 10_000_000:
        raise TwinError(f"{where}: encoders: counts_per_rev × gear_ratio = {wheel:.9g} counts per wheel revolution; "
                        f"allowed: a whole number from 4 to 10000000 (the estimators count whole counts of a wheel)")
    lat = t.get("latency")
    if not (_is_number(lat) and 0.0 <= lat <= 1.0):
        raise TwinError(f"{where}: encoders.latency: {'missing' if lat is None else shown(lat)}; allowed: a number in "
                        f"[0, 1] s (from the measured instant to the row's t)")
    lat = _whole_periods(float(lat), rate, "encoders.latency", notes)
    return EncoderSpec(int(whole), lat)


# each format stream's columns -> unit ("C": the commands' unit)
_STREAM_UNITS = {
    "imu": {"t": "s", "gyro_x": "rad/s", "gyro_y": "rad/s", "gyro_z": "rad/s", "accel_x": "m/s^2",
            "accel_y": "m/s^2", "accel_z": "m/s^2"},
    "encoders": {"t": "s", "left": "counts", "right": "counts"},
    "commands": {"t": "s", "ul": "C", "ur": "C"},
    "truth": {"t": "s", "theta": "rad", "theta_dot": "rad/s", "psi": "rad", "psi_dot": "rad/s", "alpha": "rad",
              "alpha_dot": "rad/s", "psi_l": "rad", "psi_r": "rad", "gyro_bias_x": "rad/s", "gyro_bias_y": "rad/s",
              "gyro_bias_z": "rad/s"},
    "duty": {"t": "s", "duty_l": "1", "duty_r": "1"},
}
_SAME_UNIT = {"m/s²": "m/s^2", "N*m": "N·m", "N.m": "N·m"}  # spellings of one unit


def _declared_streams(table, where: str, cunit: str):
    """(a format stream -> its file where ``[streams]`` renames it, the other streams' declarations)."""
    if table is None:
        return {}, {}
    if not isinstance(table, dict):
        raise TwinError(f"{where}: streams must be a table of [streams.NAME] tables, got {shown(table)}")
    if len(table) > MAX_STREAMS:
        raise TwinError(f"{where}: streams: {len(table)} declared; allowed: at most {MAX_STREAMS} (twin.logs.bounds)")
    files, extra, used = {}, {}, {}
    for name, d in table.items():
        key = f"streams.{name}"
        if not (0 < len(name) <= 32 and set(name) <= _NAME_CHARS and name[0].isalpha()):
            raise TwinError(f"{where}: {shown(key)}: not a stream name; allowed: lower-case letters, digits and _ "
                            f"(at most 32, a letter first)")
        if not isinstance(d, dict):
            raise TwinError(f"{where}: {key}: {shown(d)}; allowed: a table of {_keys_text(STREAM_KEYS)}")
        bad = [k for k in d if k not in STREAM_KEYS]
        if bad:
            raise TwinError(f"{where}: {key}.{bad[0]}: unknown key; allowed: {_keys_text(STREAM_KEYS)}")
        file = d.get("file", f"{name}.csv")
        if not (isinstance(file, str) and file.endswith(".csv") and len(file) > 4 and Path(file).name == file
                and "\\" not in file and file.isprintable() and file != "log.toml"):
            raise TwinError(f"{where}: {key}.file: {shown(file)}; allowed: the name of a .csv file beside log.toml "
                            f"(no directory)")
        if file in used:
            raise TwinError(f"{where}: {key}.file: {file} is also streams.{used[file]}'s; allowed: a file of its own")
        used[file] = name
        lat = d.get("latency")
        if lat is not None and not (_is_number(lat) and 0.0 <= lat <= 1.0):
            raise TwinError(f"{where}: {key}.latency: {shown(lat)}; allowed: a number in [0, 1] s (from the measured "
                            f"instant to the row's t)")
        desc = d.get("description", "")
        if not (isinstance(desc, str) and len(desc) <= 200 and desc.isprintable()):
            raise TwinError(f"{where}: {key}.description: {shown(desc)}; allowed: one line of text, at most 200 "
                            f"characters")
        cols = d.get("columns")
        if name in STREAMS:
            if lat is not None:
                raise TwinError(f"{where}: {key}.latency: the format's streams say their latency in [imu] and "
                                f"[encoders]; allowed: latency for a stream of one's own")
            if cols is not None:
                _check_format_columns(name, cols, where, cunit)
            files[name] = file
            continue
        if not isinstance(cols, dict) or len(cols) < 2:
            raise TwinError(f"{where}: {key}.columns: {'missing' if cols is None else shown(cols)}; allowed: a table "
                            f"of column name -> unit in the file's order, t = \"s\" first and at least one more")
        names = list(cols)
        if names[0] != "t" or cols["t"] != "s":
            raise TwinError(f"{where}: {key}.columns: the first column is {shown(names[0])} in "
                            f"{shown(cols[names[0]])}; allowed: t = \"s\" first (the log's one clock)")
        for c in names:
            u = cols[c]
            if not (0 < len(c) <= 32 and set(c) <= _NAME_CHARS):
                raise TwinError(f"{where}: {key}.columns.{shown(c)}: not a column name; allowed: lower-case letters, "
                                f"digits and _ (at most 32)")
            if not (isinstance(u, str) and 0 < len(u) <= 32 and u.isprintable()):
                raise TwinError(f"{where}: {key}.columns.{c}: {shown(u)}; allowed: its unit, as text (SI: \"A\", "
                                f"\"V\", \"rad/s\", \"m/s^2\", \"1\" for a pure number)")
        extra[name] = {"file": file, "columns": tuple(names[1:]), "units": tuple(cols[c] for c in names[1:]),
                       "latency": None if lat is None else float(lat), "description": desc}
    theirs = {files.get(s, f"{s}.csv"): s for s in STREAMS}  # the format's streams' files
    for name, d in extra.items():
        if d["file"] in theirs:
            raise TwinError(f"{where}: streams.{name}.file: {d['file']} is the format's {theirs[d['file']]} stream; "
                            f"allowed: a file of its own")
    return files, extra


def _check_format_columns(name: str, cols, where: str, cunit: str) -> None:
    """A declaration of a format stream's columns: exactly the format's, in its units."""
    key = f"streams.{name}.columns"
    units = _STREAM_UNITS[name]
    want = [STREAMS[name]] + ([STREAMS[name] + TRUTH_STATE] if name == "truth" else [])
    if not isinstance(cols, dict) or tuple(cols) not in want:
        raise TwinError(f"{where}: {key}: {shown(list(cols) if isinstance(cols, dict) else cols)}; allowed: "
                        f"{' or '.join(','.join(w) for w in want)} (the format's columns, each with its unit)")
    for c, u in cols.items():
        need = units[c]
        if need == "C":
            need = {"N·m": "N·m", "duty": "1", "V": "V"}[cunit]
            ok = u in (need, cunit) or _SAME_UNIT.get(u) == need
        else:
            ok = u == need or _SAME_UNIT.get(u) == need
        if not ok:
            raise TwinError(f"{where}: {key}.{c}: {shown(u)}; allowed: {need!r} (the format's units are SI: convert "
                            f"when writing the log)")


def _scenario_v2(root: Path, m: dict, where: str):
    """A version-2 manifest's optional ``scenario`` (where the log came from): read for its
    estimator's own parameters (``sensors.estimator_params``) and its physics rate only."""
    if "scenario" not in m:
        if "set" in m:
            raise TwinError(f"{where}: set: given without scenario; allowed: set with a scenario only")
        return None
    return _load_named(root, where, m["scenario"], m.get("set", []))


def _extra_stream(root: Path, where: str, name: str, decl: dict) -> Stream:
    """A declared stream of one's own (``[streams.NAME]``), read as the format's are: in time order,
    numbers or empty fields (NaN), within the bounds of :mod:`twin.logs.bounds`."""
    path = root / decl["file"]
    cols = ("t",) + decl["columns"]
    groups = tuple((j, j + 1) for j in range(1, len(cols)))
    try:
        inside(path, root, "stream")
        out, _ = read_stream(path, [(cols, groups)], tolerance=TIME_TOLERANCE,
                             also=f" (as log.toml's [streams.{name}] declares)")
    except FileNotFoundError:
        raise TwinError(f"{where}: streams.{name}: {decl['file']} is missing; allowed: a declared stream's file "
                        f"beside log.toml (or no [streams.{name}])") from None
    return Stream(name, decl["file"], decl["columns"], decl["units"], out[:, 0], out[:, 1:], decl["latency"],
                  decl["description"])


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
    extra = [f"sensors.encoder_counts={counts}", f"sensors.imu_position=[{', '.join(map(repr, pos))}]",
             "sensors.sensing=\"estimated\""]
    return _load_named(root, where, m.get("scenario", "paper-exp1"), m.get("set", []), extra)


def _load_named(root: Path, where: str, name, items, extra=()):
    """Scenario ``name`` (a built-in, or a .toml file beside log.toml) with ``items`` and then
    ``extra`` as --set items, or a one-line :class:`TwinError` naming log.toml's key."""
    # only for a log that names a scenario: twin.scenarios imports this format back (a cycle at the top)
    from twin.scenarios import load_scenario

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
    try:
        return load_scenario(name, [*items, *extra], within=root)
    except TwinError as exc:
        raise TwinError(f"{where}: scenario: {exc}") from None


def _stream(root: Path, name: str, required: bool, integers: bool = False, need_all: bool = False,
            file: str | None = None):
    """Stream ``name`` as a float array (rows, columns), in file order; None if absent and optional.
    ``file``: its file where log.toml's ``[streams.NAME]`` names one (default ``NAME.csv``).

    The log's own file only: one that leads out of the log's directory (a symbolic link to
    another file) is refused before it is opened; read row by row within the bounds of
    :mod:`twin.logs.bounds` (:func:`twin.logs.streams.read_stream`)."""
    path = root / (file or f"{name}.csv")
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


def _check_gravity(path: Path, accel: np.ndarray, t: np.ndarray, after: str = "") -> None:
    """The accelerometer's mean over its first 0.1 s of readings (the robot at rest): about g, mostly on +z
    (``after``: what the message adds, e.g. " after [imu] orientation" for readings turned into body axes)."""
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
                        f"({mean[axis]:+.3g} m/s²){after}; allowed: body axes with z up (+g on accel_z at rest, "
                        f"upright){'; say the IMU’s mounting in [imu] orientation' if after else ''}")


# ---- writing ---------------------------------------------------------------------------------------
def write_log(run, out, scenario=None, initial_heading: float | None = None, source: str = "twin run",
              version: int = VERSION) -> Path:
    """Write twin run ``run`` (a :class:`twin.sim.runs.Run` logged at every control step, with
    simulated sensors) as a sensor log in directory ``out``, the truth stream included.

    ``version``: 2 (the default) writes every figure the estimators are built with into
    log.toml: the sensors as the run's estimator believed them (the scenario's
    ``[sensors.believed]``, by default the true specification: noise, ranges, rate, latency,
    mounting point, the twin's IMU means over each sample interval in the body's axes), the
    encoders (on the wheels), the motors (or ideal torque sources), the commands (N·m, held)
    and the model; 1 writes the version-1 manifest, whose figures come from the scenario. The
    streams are the same either way, and so is every number a replay of the log gives.

    ``scenario``: the :class:`~twin.scenarios.Scenario` it ran (its name or file, and --set
    items, go into log.toml, so the estimators are built for the same sensors and motors);
    ``initial_heading`` (rad): α at t = 0 as the run's estimator was told it (default: the
    scenario's ``initial.alpha``, else the truth's first α); ``source``: what wrote it (log.toml's
    free-text ``source``; a sweep's sample adds which sample it is). A run with DC motors also
    gets duty.csv, the duty its drivers applied (``run.signal("duty_l")``, ``"duty_r"``). A run
    with more sensor channels (:mod:`twin.sensors.types`: the motor current) gets one stream each,
    ``<type>.csv`` (t and the channel's columns, each row a sample as it reached the estimator),
    declared in log.toml's ``[streams.<type>]`` with its units and its figures in
    ``[sensors.<type>]`` (version 2; a version-1 manifest cannot declare them, so they are left
    out of it)."""
    if run.measurements is None or run.sensor_config is None:
        raise TwinError("a sensor log needs a run with simulated sensors (sensing is ideal here)")
    if getattr(run, "log_every", 1) != 1:
        raise TwinError(f"a sensor log needs every control step (log_every = 1), got {run.log_every}")
    if isinstance(version, bool) or version not in VERSIONS:
        raise TwinError(f"write_log: version {version!r}; allowed: {', '.join(map(str, VERSIONS))}")
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
    channel_lines = _write_channels(run, out) if version >= 2 else []
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
    lines = [f'format = "{FORMAT}"', f"version = {version}", f"control_rate = {float(cfg.control_rate)!r}",
             f"wheel_radius = {float(p.r)!r}", f"track = {float(2.0 * p.b)!r}"]
    if version == 1:
        lines += [f"encoder_counts = {int(sensors.encoders.counts_per_rev)}",
                  f"imu_position = [{', '.join(repr(float(v)) for v in sensors.imu.position)}]"]
    lines += [f"initial_heading = {float(heading)!r}"]
    believed = None
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
        overrides = list(scenario.overrides)
        robot_file = scenario.data.get("robot", "paper")
        if Path(robot_file).suffix == ".toml":  # a robot file of one's own: copied beside the log too
            (out / "robot.toml").write_bytes(Path(robot_file).read_bytes())
            overrides = [o for o in overrides if o.partition("=")[0].strip() != "robot"] + ['robot="robot.toml"']
        lines += [f"scenario = {_toml_str(name)}",
                  "set = [" + ", ".join(_toml_str(o) for o in overrides) + "]"]
        believed = scenario.believed_sensor_config()
    robot = [f"{k} = {float(getattr(p, k))!r}" for k in p.__dataclass_fields__ if k not in ("r", "b", "n_xb")]
    lines += [f"source = {_toml_str(source)}", ""]
    if version == 1:
        lines += ["[robot]", *robot, f"n_xb = {float(p.n_xb)!r}", "", "[commands]", 'unit = "N·m"', ""]
    else:  # every figure the run's estimator was built with (the believed sensors: by default the true ones)
        lines += [*_manifest_v2(believed or sensors, getattr(cfg, "motor", None)), "[robot]", *robot,
                  f"n_xb = {float(p.n_xb)!r}", "", *channel_lines]
    if state:  # the sensors' drawn constants and the plant's radius: the rest of the EKF's state truth
        vec = lambda v: "[" + ", ".join(repr(float(e)) for e in v) + "]"  # noqa: E731
        lines += ["[truth]", f"gyro_scale = {vec(st['gyro_scale'])}", f"accel_scale = {vec(st['accel_scale'])}",
                  f"encoder_phase = {vec(st['encoder_phase'])}", f"wheel_radius = {float(cfg.params.r)!r}", ""]
    (out / "log.toml").write_text("\n".join(lines), encoding="utf-8")
    return out


def _write_channels(run, out: Path) -> list:
    """Write each extra sensor channel of ``run`` (``run.measurements.extra``) as ``<type>.csv``
    (its rows: the samples that reached the estimator, at the instant they did); the log.toml
    lines declaring them (``[streams.<type>]`` with the units, ``[sensors.<type>]`` the figures of
    the run's spec). A channel file of an earlier log in ``out`` that this run has not is removed."""
    ms = run.measurements
    have = getattr(ms, "extra", None) or {}
    num = lambda v: repr(float(v))  # noqa: E731
    lines = []
    for t in extra_types():
        c = t.channels[0]
        path = out / f"{t.name}.csv"
        spec = run.sensor_config.spec(t.name)
        if c.name not in have or spec is None:
            path.unlink(missing_ok=True)
            continue
        values, has = have[c.name]
        with open(path, "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(("t",) + c.columns) + "\n")
            for i in np.flatnonzero(has):
                fh.write(",".join([num(ms.t[i]), *(num(v) for v in values[i])]) + "\n")
        cols = ", ".join(f'{k} = "{c.unit}"' for k in c.columns)
        lines += [f"[streams.{t.name}]", f'file = "{t.name}.csv"', f'columns = {{ t = "s", {cols} }}',
                  f"description = {_toml_str(t.doc)}", "", f"[sensors.{t.name}]"]
        for k in t.keys:
            v = getattr(spec, k)
            if v is not None:
                lines.append(f"{k} = {num(v)}")
        lines.append("")
    return lines


def _manifest_v2(sensors, motor) -> list:
    """log.toml's [imu], [imu.gyro], [imu.accel], [encoders], [commands] and [motor] tables (version
    2) of a twin run: its sensors' figures (``sensors``, a SensorConfig), its motors (``motor``,
    DCMotorParams, or None for ideal torque sources), commands in N·m held over each period."""
    imu, enc = sensors.imu, sensors.encoders
    num = lambda v: repr(float(v))  # noqa: E731  (the shortest repr: the float reads back exactly)
    lines = ["[imu]", 'sampling = "mean"  # the twin\'s IMU: the mean over each sample interval',
             f"rate = {num(imu.rate)}", f"latency = {num(imu.latency)}",
             f"position = [{', '.join(num(v) for v in imu.position)}]", "orientation = [0.0, 0.0, 0.0]", ""]
    for name, t in (("gyro", imu.gyro), ("accel", imu.accel)):
        lines += [f"[imu.{name}]", f"noise_density = {num(t.noise_density)}",
                  f"bias_random_walk = {num(t.bias_random_walk)}"]
        if t.bias_correlation_time is not None:
            lines.append(f"bias_correlation_time = {num(t.bias_correlation_time)}")
        lines += [f"turn_on_bias = {num(t.turn_on_bias)}", f"scale_factor_error = {num(t.scale_factor_error)}",
                  f"full_scale = {num(t.full_scale)}", f"bits = {int(t.bits)}", ""]
    lines += ["[encoders]", f"counts_per_rev = {int(enc.counts_per_rev)}", 'on = "wheel"',
              f"latency = {num(enc.latency)}", "", "[commands]", 'unit = "N·m"', 'semantics = "held"', ""]
    if motor is None:
        lines += ["[motor]", 'kind = "ideal"', ""]
    else:
        lines += ["[motor]", 'kind = "dc"', f"supply_voltage = {num(motor.supply_voltage)}",
                  f"stall_torque = {num(motor.stall_torque)}", f"no_load_speed = {num(motor.no_load_speed)}"]
        if motor.current_limit is not None:
            lines.append(f"current_limit = {num(motor.current_limit)}")
        lines += [f"pwm_bits = {int(motor.pwm_bits)}", f"dead_band = {num(motor.dead_band)}",
                  f"inductance = {num(motor.inductance)}",
                  f"back_emf_compensation = {'true' if motor.back_emf_compensation else 'false'}", ""]
    return lines


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


__all__ = ["COMMAND_KEYS", "COMMAND_UNITS", "COMMAND_UNITS_V2", "ENCODER_KEYS", "ENCODER_MOUNTS", "FORMAT", "IMU_KEYS",
           "MOTOR_KINDS", "SAMPLINGS", "SEMANTICS", "STREAMS", "STREAM_KEYS", "SensorLog", "Stream", "TIME_TOLERANCE",
           "TRIAD_KEYS", "TRUTH_KEYS", "TRUTH_STATE", "VERSION", "VERSIONS", "motor_keys", "read_log", "robot_keys",
           "write_log"]
