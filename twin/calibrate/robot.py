"""Calibration of the robot: its physical parameters from one or several logs, by the continuous model.

(A log's motor current, :attr:`twin.logs.format.SensorLog.channels`, is not used by this model yet:
the twin-stepping fit of :mod:`twin.calibrate.run` and :mod:`twin.calibrate.fit` uses it.)

What is fitted: the robot's physical parameters (:data:`twin.calibrate.fit.PLANT_NAMES`, the
motors' figures on request), shared by every log, and per log the IMU's constants (biases and
scale factors change at every power-up) and every window's start state θ, θ̇, ψ̇, α̇ and its two
encoder offsets. The model is :mod:`twin.calibrate.physical` (equation (1) by RK4 at 1 kHz or
more, with the motors, the commands held or sampled as the log says), so the numbers are the
robot's, not those of a discretisation; :func:`twin.calibrate.physical.twin_parameters` maps
them to the PyBullet twin.

A log whose rows are off its control instants (a hobby firmware's, one row every 30–33 ms: put on
the regular grid, its rows land up to a period off their times, and the true robot misfits its
windows by 3.6–7 σ² per residual, the pitch gyro at ~3 σ) has each reading taken at its row's own
time (:func:`row_timing`, :func:`twin.calibrate.physical.simulate_nodes`): a point sample at the
row's time, a mean sample over its own interval, commands sampled as straight lines between their
rows' times or held from each row's time. The readings are weighed by the noise a replay uses
(:func:`imu_sigma`: the log's figures, or the noise measured from its readings where it gives
none or they contradict it).

Windows are :data:`WINDOW_S` seconds long (at least :data:`MIN_PERIODS` control periods), so a
log at 30 Hz and one at 1 kHz both give windows over which an open-loop error grows a few times
at most (the unstable pole of a balancing robot is 10–20/s).

Solver: Levenberg–Marquardt on the parameters and every window's states together, the window
states eliminated per window (the Schur complement of the block-diagonal normal equations:
a sparse bundle adjustment, Triggs et al. 2000), the Jacobian by forward differences with every
perturbed copy of every window simulated in one batch, the sensor constants' and the offsets'
columns exact (they enter linearly); near the optimum the dampings are stepped as ln(d_b + d_w) and
ln d_b (:func:`_damping_pair`), and a rejected step is halved before it is damped more (a curved
valley of equal cost otherwise made the fit crawl). Windows a push or a bump spoils are left out by the χ² test
of :func:`twin.calibrate.fit.outlier_limit`, chosen again at each estimate. The uncertainty is
that of :mod:`twin.calibrate.fit` (Jacobian, clustered sandwich, bootstrap over 1 s stretches).

Every reduction is an elementwise numpy operation or a Python loop (the 6 × 6 window systems by
elementwise Cholesky, the parameters' system by :func:`estimation.detlinalg.solve`): no BLAS.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from estimation.detlinalg import solve
from twin.calibrate import fit as F
from twin.calibrate.fit import Calibration
from twin.calibrate.identify import assess
from twin.calibrate import physical as P
from twin.calibrate.model import step_windows
from twin.calibrate.parameters import PARAMETERS
from twin.calibrate.readings import encoder_angles
from twin.calibrate.validate import aggregate
from twin.calibrate.windows import Windows, cut, on_rows, streams
from twin.errors import TwinError
from twin.logs.noise import choose

WINDOW_S = 0.1  # s: a window's length (at least MIN_PERIODS control periods)
MIN_PERIODS = 3  # control periods a window has at least
MIN_SECONDS = 5.0  # s of usable windows (every reading present) the logs must give together
LATENCIES = (0, 1, 2, 3)  # control periods tried for the IMU latency
PROFILE_WINDOWS = 40  # windows per log the IMU latency's profile is computed on
TURN_RATE = 0.2  # rad/s: a log whose |α̇| never reaches this does not excite the yaw inertia
MAX_ITERATIONS = 60  # Levenberg–Marquardt iterations per fit
BLOWN = 1e3  # σ: each residual of a window the model throws over (NaN or infinite)
STEP_FRACTIONS = (1.0, 0.5, 0.25)  # of a step tried before more damping
NEAR_GAUSS_NEWTON = 1e-2  # damping λ (relative to the diagonal) below which a step is nearly Gauss–Newton's
ROUGH_ITERATIONS = 20  # an intermediate fit's (the window set still to change)
FINAL_ITERATIONS = 40  # the last fit's (from the trimmed fit's optimum, for the Jacobian there)
TOLERANCE = 1e-7  # relative decrease of the cost below which the final fit has converged
ROUGH = 1e-4  # the same for the intermediate fits (the window set or the stage still to change)
STATE_STEP = np.array([1e-7, 1e-6, 1e-6, 1e-6])  # finite-difference steps of θ (rad), θ̇, ψ̇, α̇ (rad/s)
PARAM_STEP = 1e-6  # finite-difference step of ln(factor) of a physical parameter
FIRST_LIMIT = 3.0  # a window costing more than this × the median is left out of a first fit
MAX_LOG_STEP = 0.3  # largest change of ln(factor) a step may make (a trust region on the physical parameters)
STATE_COLUMNS = (0, 1, 3, 5)  # θ, θ̇, ψ̇, α̇ of a window's start state are fitted; ψ, α stay the EKF's
# reading channels: gyro x, y, z (rad/s), accel x, z (m/s²); which sensor constant acts on each
CHANNEL_BIAS = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x", None)
CHANNEL_SCALE = ("gyro_scale_x", "gyro_scale_y", "gyro_scale_z", "accel_scale_x", "accel_scale_z")
# the IMU's constants the continuous model fits: the twin's set and the roll gyro's scale factor (it
# reads −α̇ sin θ: left out, a 2 % scale error there moved the body's mass by 1 % on a log that turns)
SENSORS = F.SENSOR_NAMES[:4] + ("gyro_scale_x",) + F.SENSOR_NAMES[4:]
STAGE_A = ("gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x")
STAGE_B = ("m_b", "l", "n_yb", "d_b", "d_w") + STAGE_A
CONSISTENT_Z = 3.0  # |z| of a parameter's difference between two fits beyond which the robots differ


def twin_lags(log):
    """(τ_w, τ_j) in s if ``log`` is the PyBullet twin's own (written by ``twin`` from a scenario whose
    plant model is "bullet"), else None: how long its stepping's dampings lag.

    The twin holds the wheel–ground damping over each control period T from the rates at its start
    and steps by semi-implicit Euler at h (damping from the step's starting rates): against the
    continuous equations the wheel–ground damping lags by τ_w = T/2 + h/2 and the joint damping
    (d_b and the motors' c_e) by τ_j = h/2. A damping c lagging by τ acts as an inertia −c τ on its
    coordinate (:func:`twin.calibrate.physical.constants`): fitted with that, a twin log gives back
    the twin's own parameters, and :func:`twin.calibrate.physical.twin_parameters` goes the other
    way. (The balancing robot's m11 m22 − m12² is a small difference of large terms: without this,
    a twin log's pitch inertia comes back at about 0.58 of the twin's.)"""
    src = str(log.manifest.get("source", "") or "")
    if log.scenario is None or not src.startswith("twin "):
        return None
    data = log.scenario.data
    if (data.get("plant") or {}).get("model", "bullet") != "bullet":
        return None
    h = 1.0 / float(data["rates"]["physics"])
    return 0.5 / float(log.control_rate) + 0.5 * h, 0.5 * h


def window_periods(control_rate: float, window_s: float = WINDOW_S) -> int:
    """Control periods of a window of ``window_s`` s at ``control_rate`` Hz (at least MIN_PERIODS)."""
    return max(MIN_PERIODS, int(round(window_s * float(control_rate))))


def log_name(name: str, i: int) -> str:
    """A sensor constant's name for log ``i`` (0-based): the first log's is the plain name, the
    others' ``name@k`` (k = i + 1)."""
    return name if i == 0 else f"{name}@{i + 1}"


def base_name(name: str) -> str:
    return name.split("@", 1)[0]


# ---- one log's windows -----------------------------------------------------------------------------
@dataclass
class Group:
    """One log's windows for the fit: ``w`` the :class:`~twin.calibrate.windows.Windows` (``w.drive``
    per period; ``drive`` (W, N, 2) held or (W, N + 1, 2) sampled at the instants), the model's
    fixed figures and the log's index ``index``."""

    log: object
    index: int
    w: Windows
    drive: np.ndarray
    sampled: bool
    point: bool
    motor: tuple | None  # (stall torque N·m, no-load speed rad/s) of the log, or None: ideal sources
    sigma: np.ndarray  # (5,) white-noise σ of the IMU channels
    enc_sigma: float
    # a log whose rows are off its control instants (jittered): each reading at its row's own time
    # (:func:`row_timing`); None: every row on its instant (the readings at the periods' ends)
    timing: dict | None = None

    @property
    def count(self) -> int:
        return self.w.count

    @property
    def periods(self) -> int:
        return self.w.periods

    @property
    def rate(self) -> float:
        return float(self.log.control_rate)

    @property
    def residuals_per_window(self) -> int:
        return self.periods * 5 + (self.periods + 1) * 2

    def subset(self, keep) -> "Group":
        keep = np.asarray(keep)
        timing = None
        if self.timing is not None:
            timing = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in self.timing.items()}
        return replace(self, w=self.w.subset(keep), drive=self.drive[keep], timing=timing)

    def head(self, periods: int) -> "Group":
        """The group's windows cut to their first ``periods`` periods."""
        w = self.w
        head_w = Windows(w.starts, w.S0, w.drive[:, :periods], w.imu[:, :periods], w.angles[:, :periods + 1],
                         w.imu_latency, w.streams)
        timing = None
        if self.timing is not None:
            timing = dict(self.timing)
            for k in ("imu_a", "imu_b", "imu_drive"):
                timing[k] = timing[k][:, :periods]
            timing["enc"] = timing["enc"][:, :periods + 1]
        return replace(self, w=head_w, drive=self.drive[:, :periods + 1 if self.sampled else periods],
                       timing=timing)


def log_streams(log):
    """The log on its control instants (:func:`twin.calibrate.windows.streams`) with ``drive_at``
    (n, 2): the drive at each instant as the model takes it (wheel torques in N·m for ideal
    sources, else the duty), and whether it is ``sampled`` (joined by straight lines) or held."""
    st = streams(log)
    st.imu_sigma = imu_sigma(log, st.imu_sigma)
    sampled = getattr(log, "command_semantics", "held") == "sampled"
    unit = getattr(log, "command_unit", "N·m")
    if log.duty is None and log.motor is not None and unit in ("duty", "V"):
        # the commands are past the driver (read as duty × stall torque): the duty itself, not the
        # driver's response to a torque command
        drive = log.commands / log.motor.stall_torque
        if sampled:
            at = np.column_stack([np.interp(st.t, log.commands_t, drive[:, j]) for j in range(2)])
        else:
            idx = np.searchsorted(log.commands_t, st.t + 1e-6 / log.control_rate, side="right") - 1
            at = drive[np.clip(idx, 0, None)]
        st.drive, st.drive_is_duty = np.clip(at, -1.0, 1.0), True
    elif sampled and log.motor is None:
        st.drive = np.column_stack([np.interp(st.t, log.commands_t, log.commands[:, j]) for j in range(2)])
    st.drive_at = _drive_at(log, st, sampled)
    rows = on_rows(st, log, st.drive_at)
    if rows is not None:  # a jittered logger's rows: the windows made of its rows, each at its time
        rows.drive_at = st.drive_at
        rows.on_rows = True  # its "instants" are the rows' times: off any regular grid
        st = rows
    return st, sampled


def _drive_at(log, st, sampled: bool):
    """The drive as the model takes it (as :func:`log_streams`' ``drive``) at any times (s): from the
    rows' own times, straight lines between them (sampled) or each held from its row's time, for a
    log whose rows are jittered off the control instants. Where the drive is reconstructed at the
    instants (N·m commands through a driver, from the estimated speeds) it is that, held."""
    def rows(t_rows, values, lo=-np.inf, hi=np.inf):
        t_rows = np.maximum.accumulate(np.asarray(t_rows, dtype=float))

        def at(x):
            x = np.asarray(x, dtype=float)
            if sampled:
                out = np.stack([np.interp(x, t_rows, values[:, j]) for j in range(2)], axis=-1)
            else:
                i = np.clip(np.searchsorted(t_rows, x + 1e-9, side="right") - 1, 0, len(t_rows) - 1)
                out = values[i]
            return np.clip(out, lo, hi)
        return at

    unit = getattr(log, "command_unit", "N·m")
    if log.duty is not None:
        return lambda x: _held(log.duty_t, log.duty, x)
    if log.motor is not None and unit in ("duty", "V"):
        return rows(log.commands_t, log.commands / log.motor.stall_torque, -1.0, 1.0)
    if log.motor is None:
        return rows(log.commands_t, np.asarray(log.commands, dtype=float))
    return lambda x: _held(st.t, st.drive, x)


def _held(t_rows, values, x):
    t_rows = np.maximum.accumulate(np.asarray(t_rows, dtype=float))
    i = np.clip(np.searchsorted(t_rows, np.asarray(x, dtype=float) + 1e-9, side="right") - 1, 0, len(t_rows) - 1)
    return np.asarray(values, dtype=float)[i]


def imu_sigma(log, given):
    """(5,) the white-noise σ per row of the IMU channels the fit weighs the readings by: the
    figures a replay uses (:func:`twin.logs.noise.choose`, mode ``log``): the log's own, except where
    it gives none or its readings contradict them, then the noise measured from the readings. A
    hobby robot's rows (point samples of a 1 kHz loop, the motors shaking the board) carry 25–100×
    the datasheet's density at the row rate: weighed by the datasheet's figure, the fit's cost was
    ~3000 per residual and the vibration drove the parameters. ``given`` the log's figures' σ."""

    try:
        _, sens, _ = choose(log)
    except TwinError:  # figures the IMU cannot hold: the log's own
        return given
    if sens is log.sensors:
        return given
    dt = 1.0 / sens.imu.rate
    g, a = sens.imu.gyro.white_sigma(dt), sens.imu.accel.white_sigma(dt)
    return np.array([g, g, g, a, a])


def make_group(log, st, sampled: bool, index: int, imu_latency: int, periods: int, stride=None) -> Group:
    w = cut(st, imu_latency, periods, stride)
    n = len(st.t)
    if sampled:
        j = np.clip(w.starts[:, None] + np.arange(periods + 1)[None, :], 0, n - 1)
        drive = st.drive[j]
    else:
        drive = w.drive
    motor = None
    if log.motor is not None:
        motor = (float(log.motor.stall_torque), float(log.motor.no_load_speed))
    elif st.drive_is_duty:
        raise TwinError(f"{log.path}: a duty drive needs the log's motors")
    point = getattr(log, "sampling", "mean") == "point"
    return Group(log, index, w, drive, sampled, point, motor, np.asarray(st.imu_sigma, dtype=float),
                 float(st.encoder_sigma), row_timing(st, w, point))


JITTER_S = 1e-6  # s: a row further than this from its control instant is taken at its own time


def row_timing(st, w: Windows, point: bool) -> dict | None:
    """Where a log's rows are off its control instants (a logger's jitter), the times each window's
    readings are of, for the model to take them there: None where every row used is on its instant.

    A window then starts at the earliest of its readings' times (``start``, s; at most a period
    before its first instant) and is integrated over ``M`` RK4 steps of ``h`` s (the log's
    :func:`~twin.calibrate.physical.substeps`); ``enc`` (W, N + 1) s from the start: the encoder
    rows' times; ``imu_b`` (W, N) the IMU rows' (a point sample's instant, a mean sample's
    interval's end) and ``imu_a`` (W, N) the interval's start (the IMU row before it); a latency of
    whole periods d puts a reading d periods before its row's time. ``fine`` (W, 2 M + 1, 2) the
    drive at every half step and ``imu_drive`` (W, N, 2) at the IMU rows' times (a point sample's
    acceleration), from the log's rows at their own times (:func:`_drive_at`)."""
    if st.imu_time is None or st.encoder_time is None or w.count == 0 or not hasattr(st, "drive_at"):
        return None
    rate = float(st.control_rate)
    N = w.periods
    d, de = w.imu_latency, st.encoder_latency
    j = w.starts[:, None] + np.arange(N)[None, :]
    jb = j + 1 + d
    je = w.starts[:, None] + np.arange(N + 1)[None, :] + de
    tb = st.imu_time[jb] - d / rate
    ta = st.imu_prev_time[jb] - d / rate
    te = st.encoder_time[je] - de / rate
    grid_b, grid_e = st.t[j + 1], st.t[je - de]
    if not point and not np.all(np.isfinite(ta)):
        return None
    off = max(float(np.nanmax(np.abs(tb - grid_b))), float(np.nanmax(np.abs(te - grid_e))))
    if not point:
        off = max(off, float(np.nanmax(np.abs(ta - st.t[j]))))
    if not off > JITTER_S and not getattr(st, "on_rows", False):
        return None
    start = np.minimum(np.minimum(te[:, 0], tb[:, 0]), st.t[w.starts])
    if not point:
        start = np.minimum(start, ta[:, 0])
    k = P.substeps(rate)
    h = 1.0 / (rate * k)
    rel_e, rel_b, rel_a = te - start[:, None], tb - start[:, None], ta - start[:, None]
    span = float(np.max(rel_e[:, -1]) if N == 0 else max(np.max(rel_e), np.max(rel_b)))
    M = max(1, int(math.ceil(span / h - 1e-9)))
    fine_t = start[:, None] + (0.5 * h) * np.arange(2 * M + 1)[None, :]
    return {"start": start, "M": M, "h": h, "enc": rel_e, "imu_b": rel_b,
            "imu_a": rel_a if not point else rel_b, "fine": st.drive_at(fine_t), "imu_drive": st.drive_at(tb)}


# ---- the model of a set of logs --------------------------------------------------------------------
class RobotModel:
    """The fitted vector: ``phys`` (physical parameters as ln(value / the reference log's model)),
    then each log's ``sensors`` (values). ``names`` in that order (a log's sensor constants after
    the first log are named ``name@k``). Implements what :mod:`twin.calibrate.identify` and
    :mod:`twin.calibrate.output` ask of a plant."""

    def __init__(self, logs, phys, sensors, physics_rate=None, fixed=None):
        self.logs = list(logs)
        ref = self.logs[0]
        self.model, self.motor = ref.model, ref.motor
        self.phys = tuple(phys)
        self.sensors = tuple(sensors)
        self.fixed = dict(fixed or {})
        self.names = self.phys + tuple(log_name(n, i) for i in range(len(self.logs)) for n in self.sensors)
        self.control_rate = float(ref.control_rate)
        self.physics_rate = P.substeps(self.control_rate) * self.control_rate  # the integration rate
        self.position = tuple(ref.sensors.imu.position)
        self.b_r = ref.model.b / ref.model.r
        for n in self.phys:
            if PARAMETERS[n].group == "motor" and self.motor is None:
                raise TwinError(f"{n} needs DC motors; the log's robot has ideal torque sources")

    def base(self, name: str) -> float:
        n = base_name(name)
        if n in F.PLANT_NAMES:
            return float(getattr(self.model, n))
        if n in F.MOTOR_NAMES:
            return float(getattr(self.motor, n))
        return 0.0

    def scaled(self, name: str) -> bool:
        return base_name(name) in F.PLANT_NAMES or base_name(name) in F.MOTOR_NAMES

    def to_value(self, name: str, x: float) -> float:
        return self.base(name) * math.exp(float(x)) if self.scaled(name) else float(x)

    def from_value(self, name: str, value: float) -> float:
        return math.log(value / self.base(name)) if self.scaled(name) else float(value)

    def p0(self) -> np.ndarray:
        return np.array([self.from_value(n, self.fixed[n]) if n in self.fixed else 0.0 for n in self.names])

    def physical(self, p) -> dict:
        """Every physical parameter's value (SI) for vector p: fitted ones from p, others at the
        reference log's model (or ``fixed``)."""
        v = {n: self.base(n) for n in F.PLANT_NAMES}
        if self.motor is not None:
            v.update({n: self.base(n) for n in F.MOTOR_NAMES})
        v.update({n: x for n, x in self.fixed.items() if n in v})
        for n, x in zip(self.phys, p[:len(self.phys)]):
            v[n] = self.to_value(n, x)
        return v

    def sensor_values(self, p, i: int) -> dict:
        v = {n: 0.0 for n in SENSORS}
        v.update({base_name(n): x for n, x in self.fixed.items() if n in SENSORS or "@" in n
                  and n.endswith(f"@{i + 1}")})
        k0 = len(self.phys) + i * len(self.sensors)
        for j, n in enumerate(self.sensors):
            v[n] = float(p[k0 + j])
        return v

    def values(self, p) -> dict:
        out = self.physical(p)
        for i in range(len(self.logs)):
            for n, x in self.sensor_values(p, i).items():
                out[log_name(n, i)] = x
        return out

    def sensor_columns(self, i: int) -> list:
        k0 = len(self.phys) + i * len(self.sensors)
        return list(range(k0, k0 + len(self.sensors)))

    # -- the model ---------------------------------------------------------------------------------
    def truth(self, g: Group, phys_list: list, S: np.ndarray) -> np.ndarray:
        """True readings (B, N, 5) and states of windows: S (m·W, 6) for m parameter sets
        ``phys_list`` (dicts), each applied to its W rows; returns (readings, X)."""
        W = g.count
        m = len(phys_list)
        rows = {n: np.repeat(np.array([pv[n] for pv in phys_list]), W) for n in phys_list[0]}
        robot = g.log.model
        hold = twin_lags(g.log)
        motor = None
        if g.motor is not None:
            stall = rows.get("stall_torque", g.motor[0])
            nl = rows.get("no_load_speed", g.motor[1])
            motor = (stall, stall / nl)
        if hold:  # the twin's own log: its stepping's lagging dampings as inertia (twin_lags)
            rows["hold"] = (hold[0], hold[1], 0.0 if motor is None else motor[1])
        c = P.constants(rows, robot)
        if g.timing is not None:  # rows off the instants: each reading at its row's own time
            tm = g.timing
            rep = lambda a: np.tile(a, (m,) + (1,) * (a.ndim - 1))
            Xn, Dn = P.simulate_nodes(S, rep(tm["fine"]), c, motor, tm["h"])
            Xe = P.at_times(Xn, Dn, tm["h"], rep(tm["enc"]))
            Xb = P.at_times(Xn, Dn, tm["h"], rep(tm["imu_b"]))
            pos = g.log.sensors.imu.position
            if g.point:
                ud = rep(tm["imu_drive"])
                y = P.point_at(Xb, ud[..., 0], ud[..., 1], c, motor, pos, robot.r, robot.g)
            else:
                Xa = P.at_times(Xn, Dn, tm["h"], rep(tm["imu_a"]))
                y = P.mean_between(Xa, Xb, rep(tm["imu_b"] - tm["imu_a"]), pos, robot.r, robot.g)
            return y, Xe
        drive = np.tile(g.drive, (m, 1, 1))
        X = P.simulate(S, drive, c, motor, g.rate, sampled=g.sampled)
        if g.point:
            y = P.point_readings(X, drive, c, motor, g.log.sensors.imu.position, robot.r, robot.g, g.sampled)
        else:
            y = P.mean_readings(X, 1.0 / g.rate, g.log.sensors.imu.position, robot.r, robot.g,
                                at_end=hold is not None)
        return y, X

    @staticmethod
    def apply_sensors(y, sv: dict):
        out = y.copy()
        for ch in range(5):
            s = CHANNEL_SCALE[ch]
            b = CHANNEL_BIAS[ch]
            if s is not None:
                out[..., ch] = (1.0 + sv[s]) * y[..., ch]
            if b is not None:
                out[..., ch] += sv[b]
        return out

    def residuals(self, g: Group, p, u) -> np.ndarray:
        """(W, R) residuals in σ units of group g for vector p and window unknowns u (W, 6)."""
        S = g.w.S0.copy()
        S[:, STATE_COLUMNS] = u[:, :4]
        y, X = self.truth(g, [self._phys_rows(g, p)], S)
        return self._resid(g, self.apply_sensors(y, self.sensor_values(p, g.index)), X, u[:, 4:])

    def _phys_rows(self, g, p):
        v = self.physical(p)
        keep = ["m_b", "l", "n_yb", "n_zb", "d_b", "d_w"] + [n for n in F.MOTOR_NAMES if n in v]
        return {n: v[n] for n in keep}

    def _resid(self, g, imu, X, offsets):
        ang = encoder_angles(X, g.log.model.b / g.log.model.r, offsets)
        ri = (imu - g.w.imu) / g.sigma
        re = (ang - g.w.angles) / g.enc_sigma
        W = g.count
        return np.concatenate([ri.reshape(W, -1), re.reshape(W, -1)], axis=1)

    def jacobian(self, g: Group, p, u):
        """(r (W, R), Jp (W, R, K), Js (W, R, 6)) of group g (see the module docstring)."""
        W, K = g.count, len(self.names)
        kp = len(self.phys)
        base = self._phys_rows(g, p)
        sets = [base]
        for j, n in enumerate(self.phys):
            q = np.array(p, dtype=float)
            q[j] += PARAM_STEP
            sets.append(self._phys_rows(g, q))
        S = g.w.S0.copy()
        S[:, STATE_COLUMNS] = u[:, :4]
        Ss = [S] * len(sets)
        for j, c in enumerate(STATE_COLUMNS):
            Sj = S.copy()
            Sj[:, c] += STATE_STEP[j]
            Ss.append(Sj)
            sets.append(base)
        y, X = self.truth(g, sets, np.concatenate(Ss))
        m = len(sets)
        y = y.reshape(m, W, *y.shape[1:])
        X = X.reshape(m, W, *X.shape[1:])
        sv = self.sensor_values(p, g.index)
        off = u[:, 4:]
        r0 = self._resid(g, self.apply_sensors(y[0], sv), X[0], off)
        R = r0.shape[1]
        Jp = np.zeros((W, R, K))
        for j in range(kp):
            rj = self._resid(g, self.apply_sensors(y[1 + j], sv), X[1 + j], off)
            Jp[:, :, j] = (rj - r0) / PARAM_STEP
        N = g.periods
        for j, col in enumerate(self.sensor_columns(g.index)):
            n = self.sensors[j]
            d = np.zeros((W, N, 5))
            for ch in range(5):
                if CHANNEL_BIAS[ch] == n:
                    d[..., ch] = 1.0
                if CHANNEL_SCALE[ch] == n:
                    d[..., ch] = y[0][..., ch]
            Jp[:, :N * 5, col] = (d / g.sigma).reshape(W, -1)
        Js = np.zeros((W, R, 6))
        for j in range(4):
            rj = self._resid(g, self.apply_sensors(y[1 + kp + j], sv), X[1 + kp + j], off)
            Js[:, :, j] = (rj - r0) / STATE_STEP[j]
        e = np.zeros((W, N + 1, 2))
        e[..., 0] = 1.0 / g.enc_sigma
        Js[:, N * 5:, 4] = e.reshape(W, -1)
        e = np.zeros((W, N + 1, 2))
        e[..., 1] = 1.0 / g.enc_sigma
        Js[:, N * 5:, 5] = e.reshape(W, -1)
        return r0, Jp, Js


# ---- linear algebra without BLAS -------------------------------------------------------------------
def chol_solve(A, B):
    """X with A X = B for a batch of symmetric positive definite A (W, n, n), B (W, n, m), by an
    elementwise Cholesky factorisation (a Python loop over n; no BLAS)."""
    A = np.array(A, dtype=float)
    n = A.shape[1]
    L = np.zeros_like(A)
    for j in range(n):
        s = A[:, j, j] - np.sum(L[:, j, :j] * L[:, j, :j], axis=1)
        L[:, j, j] = np.sqrt(np.maximum(s, 1e-300))
        for i in range(j + 1, n):
            L[:, i, j] = (A[:, i, j] - np.sum(L[:, i, :j] * L[:, j, :j], axis=1)) / L[:, j, j]
    Y = np.array(B, dtype=float)
    for i in range(n):
        Y[:, i] = (Y[:, i] - np.sum(L[:, i, :i, None] * Y[:, :i], axis=1)) / L[:, i, i, None]
    for i in range(n - 1, -1, -1):
        Y[:, i] = (Y[:, i] - np.sum(L[:, i + 1:, i, None] * Y[:, i + 1:], axis=1)) / L[:, i, i, None]
    return Y


def _tt(A, B):
    """(W, a, b) = Σ_r A[w, r, a] B[w, r, b], elementwise (no BLAS)."""
    return np.einsum("wra,wrb->wab", A, B, optimize=False)


def _solve_small(A, b):
    return np.asarray(solve(A, b), dtype=float).reshape(-1)


# ---- the fit ---------------------------------------------------------------------------------------
@dataclass
class Fit:
    """A fit: ``p``, ``values`` (absolute SI), per group the window unknowns ``u`` (W, 6) and
    residuals (W, R), ``cost`` ½ Σ r², ``iterations``."""

    model: RobotModel
    groups: list
    p: np.ndarray
    u: list
    residuals: list
    cost: float
    iterations: int
    jac: list = field(default=None, repr=False)

    @property
    def values(self) -> dict:
        return self.model.values(self.p)

    def window_costs(self, i: int) -> np.ndarray:
        return np.sum(self.residuals[i] ** 2, axis=1)


def initial_u(model: RobotModel, g: Group) -> np.ndarray:
    S0 = g.w.S0
    zero = encoder_angles(S0[:, None, :], g.log.model.b / g.log.model.r, np.zeros((g.count, 2)))[:, 0, :]
    return np.column_stack([S0[:, STATE_COLUMNS], g.w.angles[:, 0, :] - zero])


def lm(model: RobotModel, groups: list, p0=None, u0=None, free=None, max_iter: int = MAX_ITERATIONS,
       tol: float = TOLERANCE, pair: bool = False) -> Fit:
    """Levenberg–Marquardt over the columns ``free`` of the vector (default: all) and every window's
    unknowns (see the module docstring); ``pair``: the dampings stepped in the coordinates of
    :func:`_damping_pair` (near the optimum: from a plant far off, they let d_b run to zero)."""
    K = len(model.names)
    p = model.p0() if p0 is None else np.array(p0, dtype=float)
    u = [initial_u(model, g) if u0 is None or u0[i] is None else np.array(u0[i], dtype=float)
         for i, g in enumerate(groups)]
    free = np.arange(K) if free is None else np.asarray(free, dtype=int)
    kf = len(free)
    use_pair = pair

    scaled = np.array([model.scaled(n) for n in model.names], dtype=bool)[free]

    def cost_of(p, u):
        rs = []
        for g, ug in zip(groups, u):
            with np.errstate(all="ignore"):
                try:
                    r = model.residuals(g, p, ug)
                except (OverflowError, ValueError, TwinError):  # a trial step to an invalid plant
                    r = np.full((g.count, g.residuals_per_window), 1e6)
            rs.append(np.where(np.isfinite(r).all(axis=1, keepdims=True), r, BLOWN))
        with np.errstate(all="ignore"):
            return 0.5 * sum(float(np.sum(r * r)) for r in rs), rs

    lam = 1e-3
    it = 0
    jac = None
    cost = None
    while it < max_iter:
        it += 1
        parts = []
        for g, ug in zip(groups, u):
            with np.errstate(all="ignore"):
                parts.append(model.jacobian(g, p, ug))
        for r, Jp, Js in parts:
            # a window the model throws over (a start far from the log) is held still at a large cost:
            # the χ² test then leaves it out
            bad = ~(np.isfinite(r).all(axis=1) & np.isfinite(Jp).all(axis=(1, 2)) & np.isfinite(Js).all(axis=(1, 2)))
            if bad.any():
                r[bad], Jp[bad], Js[bad] = BLOWN, 0.0, 0.0
                for i in np.flatnonzero(bad):
                    Js[i, np.arange(6), np.arange(6)] = 1e-6
        cost = 0.5 * sum(float(np.sum(r * r)) for r, _, _ in parts)
        jac = parts
        A = np.zeros((kf, kf))
        gp = np.zeros(kf)
        blocks = []
        pair = _damping_pair(model, free, p) if use_pair else None
        for r, Jp, Js in parts:
            Jf = Jp[:, :, free]
            if pair is not None:  # the columns of (ln(d_b + d_w), ln d_b) instead of (ln d_w, ln d_b)
                ib, iw, s_dw, dbw = pair
                Jf = Jf.copy()
                jw = Jf[:, :, iw].copy()
                Jf[:, :, iw] = jw * s_dw
                Jf[:, :, ib] = Jf[:, :, ib] - jw * dbw
            V = _tt(Js, Js)
            Wm = _tt(Jf, Js)  # (W, kf, 6)
            gs = _tt(Js, r[..., None])[..., 0]
            A += np.sum(_tt(Jf, Jf), axis=0)
            gp += np.sum(_tt(Jf, r[..., None])[..., 0], axis=0)
            blocks.append((V, Wm, gs))
        improved = False
        for _ in range(12):
            Sch = A + lam * np.diag(np.maximum(np.diag(A), 1e-12))
            rhs = gp.copy()
            sol = []
            for V, Wm, gs in blocks:
                Vd = V + lam * (np.maximum(np.diagonal(V, axis1=1, axis2=2), 1e-12)[:, :, None] * np.eye(6))
                Y = chol_solve(Vd, np.concatenate([np.swapaxes(Wm, 1, 2), gs[..., None]], axis=2))
                sol.append((Vd, Y))
                Sch -= np.sum(_tt(np.swapaxes(Wm, 1, 2), Y[:, :, :kf]), axis=0)
                rhs -= np.sum(_tt(np.swapaxes(Wm, 1, 2), Y[:, :, kf:])[..., 0], axis=0)
            dp = -_solve_small(Sch, rhs) if kf else np.zeros(0)
            if not np.all(np.isfinite(dp)) or np.any(np.abs(dp[scaled]) > MAX_LOG_STEP):
                lam *= 4.0  # a physical parameter more than e^MAX_LOG_STEP × at once: a step too long
                continue
            dus = [-(Y[:, :, kf] + np.sum(Y[:, :, :kf] * dp[None, None, :], axis=2)) for Vd, Y in sol]
            # the step, then half and a quarter of it: along a curved valley of equal cost the full
            # Gauss–Newton step overshoots, and a shorter one keeps its direction (along the valley),
            # where more damping turns it across the valley and the fit crawls
            for frac in STEP_FRACTIONS:
                pn = p.copy()
                pn[free] += frac * dp
                if pair is not None:
                    pn = _from_damping_pair(model, free, p, pn, frac * dp, pair)
                    if pn is None:  # d_w would not be positive: a step too long
                        continue
                un = [ug + frac * du for ug, du in zip(u, dus)]
                new, _ = cost_of(pn, un)
                if new < cost:
                    break
            if new < cost and pn is not None:
                rel = (cost - new) / max(cost, 1e-300)
                p, u = pn, un
                lam = max(lam / (10.0 if frac == 1.0 else 2.0), 1e-9)
                improved = True
                break
            lam *= 4.0
        # converged when a step close to Gauss–Newton's (small damping) gains little; a heavily damped
        # step gains little anywhere along a narrow valley (d_b against d_w), which is no optimum
        if not improved or (rel < tol and lam <= NEAR_GAUSS_NEWTON):
            break
    _, rs = cost_of(p, u)
    return Fit(model, groups, p, u, rs, 0.5 * sum(float(np.sum(r * r)) for r in rs), it, jac)


def _damping_pair(model, free, p):
    """Where both dampings are fitted: (index of ln d_b and of ln d_w among the free columns,
    s / d_w, d_b / d_w) for the step's coordinates ln(d_b + d_w) and ln d_b. The two damp the wheels'
    rate ψ̇ together (eq. (1): −2 (d_b + d_w) ψ̇ + 2 d_b θ̇) and the log mostly sees their sum: in
    (ln d_b, ln d_w) the valley of equal cost is curved, and Levenberg–Marquardt crawled along it
    (a hundred iterations, stopping tens of χ² short); in these coordinates it is straight."""
    names = [model.names[j] for j in free]
    if "d_b" not in names or "d_w" not in names:
        return None
    ib, iw = names.index("d_b"), names.index("d_w")
    v = model.physical(p)
    return ib, iw, (v["d_b"] + v["d_w"]) / v["d_w"], v["d_b"] / v["d_w"]


def _from_damping_pair(model, free, p, pn, dp, pair):
    """The vector after a step ``dp`` taken in the pair's coordinates (``pn`` = p + dp as if plain)."""
    ib, iw, _, _ = pair
    v = model.physical(p)
    total = (v["d_b"] + v["d_w"]) * math.exp(dp[iw])
    d_b = v["d_b"] * math.exp(dp[ib])
    d_w = total - d_b
    if not d_w > 0.0:
        return None
    out = pn.copy()
    out[free[ib]] = model.from_value("d_b", d_b)
    out[free[iw]] = model.from_value("d_w", d_w)
    return out


def refit_states(model, groups, p, u0=None, tol: float = ROUGH) -> Fit:
    """The windows' unknowns alone, the vector held at p."""
    return lm(model, groups, p0=p, u0=u0, free=np.zeros(0, dtype=int), tol=tol)


def trimmed(model, groups, p0, u0=None, free=None, rounds: int = 5, pair: bool = False):
    """(fit, keeps, u): :func:`lm` on the windows within :func:`twin.calibrate.fit.outlier_limit` of
    their log, the set chosen again from every window's cost at each estimate; ``u`` every window's
    unknowns at the fit's vector."""
    settled = refit_states(model, groups, p0, u0)
    u = settled.u
    keeps = [_keep(settled.window_costs(i), g) for i, g in enumerate(groups)]
    p = p0
    f = None
    for _ in range(rounds + 1):
        sub = [g.subset(k) for g, k in zip(groups, keeps)]
        f = lm(model, sub, p0=p, u0=[ug[k] for ug, k in zip(u, keeps)], free=free, tol=ROUGH,
               max_iter=ROUGH_ITERATIONS, pair=pair)
        p = f.p
        every = refit_states(model, groups, p, [_merge(ug, fu, k) for ug, fu, k in zip(u, f.u, keeps)])
        u = every.u
        new = [_keep(every.window_costs(i), g) for i, g in enumerate(groups)]
        if all(np.array_equal(a, b) for a, b in zip(new, keeps)):
            break
        keeps = new
    return f, keeps, u


def _keep(costs, g: Group) -> np.ndarray:
    """The windows to fit: within the χ² limit (:func:`twin.calibrate.fit.outlier_limit`) once the
    model fits the log (the median window cost within 2× its χ² mean); before that, within
    FIRST_LIMIT × the median (only the gross outliers out: at a plant still far from the robot's
    every moving window misfits, and the χ² limit would leave out the windows that inform it)."""
    nu = g.residuals_per_window - 6
    med = float(np.median(costs))
    if med <= 2.0 * nu:
        return costs <= F.outlier_limit(costs, g.residuals_per_window)
    return costs <= FIRST_LIMIT * med


def _merge(u, fu, keep):
    out = u.copy()
    out[keep] = fu
    return out


def information(f: Fit) -> F.Information:
    """The parameters' information with every window's unknowns eliminated (per window
    H_w = B_wᵀ B_w, g_w = B_wᵀ r_w with B_w = J_p − J_s (J_sᵀ J_s)⁻¹ J_sᵀ J_p)."""
    H, G = [], []
    n_res = 0
    ss = 0.0
    parts = [f.model.jacobian(g, f.p, u) for g, u in zip(f.groups, f.u)]
    for r, Jp, Js in parts:
        V = _tt(Js, Js)
        M = chol_solve(V + 1e-12 * np.eye(6), np.concatenate([_tt(Js, Jp), _tt(Js, r[..., None])], axis=2))
        K = Jp.shape[2]
        Bp = Jp - np.einsum("wra,wak->wrk", Js, M[:, :, :K], optimize=False)
        rp = r - np.einsum("wra,wa->wr", Js, M[:, :, K], optimize=False)
        H.append(_tt(Bp, Bp))
        G.append(_tt(Bp, rp[..., None])[..., 0])
        n_res += r.size
        ss += float(np.sum(r * r))
    K = len(f.model.names)
    W = sum(len(r) for r, _, _ in parts)
    dof = n_res - K - 6 * W
    return F.Information(np.concatenate(H), np.concatenate(G), ss / dof, dof)


class _Clusters:
    """What :func:`twin.calibrate.fit.covariance` and :func:`~twin.calibrate.fit.bootstrap` ask of
    windows: their start times, the logs laid end to end (a cluster never spans two logs)."""

    def __init__(self, groups):
        t, shift = [], 0.0
        for g in groups:
            t0 = g.w.t0 - g.w.t0[0]
            t.append(t0 + shift)
            shift += float(t0[-1]) + 2.0 * F.CLUSTER_S
        self.t0 = np.concatenate(t)


# ---- the procedure ---------------------------------------------------------------------------------
@dataclass
class RobotCalibration(Calibration):
    """What :func:`calibrate_robot` found: a :class:`twin.calibrate.run.Calibration` (as
    :mod:`twin.calibrate.identify` and :mod:`twin.calibrate.output` read it, ``fit`` a view of the
    first log's windows) plus the per-log ``latencies`` (periods), their ``latency_profiles`` and
    the whole fit, ``robot_fit``, with its ``groups``."""

    model_kind: str = "physical"
    latencies: list = field(default_factory=list)
    latency_profiles: list = field(default_factory=list)
    robot_fit: Fit | None = field(default=None, repr=False)


class _FitView:
    """The final fit seen as a single-log :class:`twin.calibrate.fit.Fit` (the first log's windows),
    for the report and the figure."""

    def __init__(self, f: Fit):
        self._f = f
        self.plant = _PlantView(f.model, f.groups[0])
        self.windows = f.groups[0].w
        self.values = f.values
        self.p = f.p
        self.residuals = f.residuals[0]
        g = f.groups[0]
        self.S = g.w.S0.copy()
        self.S[:, STATE_COLUMNS] = f.u[0][:, :4]
        self.offsets = f.u[0][:, 4:]
        self.cost = f.cost


class _PlantView:
    def __init__(self, model: RobotModel, g: Group):
        self._m, self._g = model, g
        self.names = model.names
        self.control_rate = g.rate
        self.physics_rate = P.substeps(g.rate) * g.rate
        self.model = model.model

    def scaled(self, n):
        return self._m.scaled(n)

    def base(self, n):
        return self._m.base(n)

    def predict(self, w, values, S, offsets):
        """(imu (W, N, 5), encoder angles (W, N + 1, 2)) of the first log's windows."""
        g = self._g
        phys = {n: values[n] for n in self._m._phys_rows(g, self._m.p0())}
        y, X = self._m.truth(g, [phys], S)
        sv = {n: values.get(n, 0.0) for n in SENSORS}
        return self._m.apply_sensors(y, sv), encoder_angles(X, g.log.model.b / g.log.model.r, offsets)


def default_names(streams_list) -> tuple[str, ...]:
    """The body (m_b, l, n_yb), the friction (d_b, d_w), the yaw inertia where a log turns, the IMU's
    biases, scale factors and latency."""
    turns = any(float(np.nanmax(np.abs(s.estimates[:, 5]))) >= TURN_RATE for s in streams_list)
    return ("m_b", "l", "n_yb") + (("n_zb",) if turns else ()) + ("d_b", "d_w") + SENSORS + ("imu_latency",)


def calibrate_robot(logs, names=None, seed: int = 0, bootstrap: int = 200, window_s: float = WINDOW_S,
                    progress=None) -> RobotCalibration:
    """Fit the robot's physical parameters (shared) and each log's IMU constants to ``logs``."""
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    logs = list(logs)
    if not logs:
        raise TwinError("no log to calibrate")
    ref = logs[0]
    for lg in logs[1:]:
        same_geometry(ref, lg)
    sts = [log_streams(lg) for lg in logs]
    all_names = tuple(names) if names is not None else default_names([s for s, _ in sts])
    turns = max(float(np.nanmax(np.abs(s.estimates[:, 5]))) for s, _ in sts)
    for n in all_names:
        if PARAMETERS[n].group == "current":
            raise TwinError(f"--parameters {n}: the continuous model does not fit the motor current yet (its samples "
                            f"are left out of it); allowed: --model twin for one log the twin wrote, or the "
                            f"parameters without the current sensor's")
        if PARAMETERS[n].group == "motor":
            if any(lg.motor is None for lg in logs):
                raise TwinError(f"--parameters {n}: the log's robot has ideal torque sources (no motor figures); "
                                "allowed without motors: " + ", ".join(k for k, v in PARAMETERS.items()
                                                                         if v.group != "motor"))
            if n == "dead_band":
                raise TwinError("--parameters dead_band: a log's duty.csv holds the duty after the dead band, so "
                                "the log cannot show it; measure it on the bench (the smallest duty that turns "
                                "the wheel)")
    phys = tuple(n for n in all_names if PARAMETERS[n].group in ("plant", "motor"))
    sens = tuple(n for n in all_names if PARAMETERS[n].group == "imu" and n != "imu_latency")
    # the IMU latency is profiled where a log does not state it (version 1 takes it from a scenario);
    # a version-2 log's own figure stands, unless --parameters names it
    fit_latency = "imu_latency" in all_names and (names is not None or any(lg.version < 2 for lg in logs))
    if not fit_latency:  # the logs' own figures stand: nothing to report as fitted
        all_names = tuple(n for n in all_names if n != "imu_latency")
    lat0 = [int(round(lg.sensors.imu.latency * lg.control_rate)) for lg in logs]
    periods = [window_periods(lg.control_rate, window_s) for lg in logs]
    groups = []
    for i, (lg, (st, sampled)) in enumerate(zip(logs, sts)):
        d = max(LATENCIES) if fit_latency else lat0[i]
        g = make_group(lg, st, sampled, i, d, periods[i])
        if not fit_latency:
            groups.append(g)
            continue
        # the windows' starts cut for the largest latency, then the readings of the log's own
        g0 = make_group(lg, st, sampled, i, lat0[i] if lat0[i] in LATENCIES else 1, periods[i])
        groups.append(g0.subset(np.isin(g0.w.starts, g.w.starts)))
    usable = sum(g.count * g.periods / g.rate for g in groups)
    need = max(MIN_SECONDS, 0.0)
    if usable < need or any(g.count < 2 for g in groups):
        which = ", ".join(f"{g.log.path}: {g.count} windows of {g.periods / g.rate:g} s" for g in groups)
        raise TwinError(f"{which}; a calibration of {len(phys) + len(sens) * len(logs)} parameters needs at least "
                        f"{need:g} s of windows with every reading (the robot moving), these give {usable:.3g} s")
    say(f"{sum(g.count for g in groups)} windows of {', '.join(sorted({f'{g.periods / g.rate:g} s' for g in groups}))}"
        f" from {len(logs)} log(s); physical model: equation (1) by RK4 at "
        f"{', '.join(sorted({f'{P.substeps(g.rate) * g.rate:g} Hz' for g in groups}))}")
    model = RobotModel(logs, phys, sens)
    K = len(model.names)
    # stage A: each log's sensor constants and the windows, the body at the log's model (from the
    # biases at zero a first joint fit can fall into a far minimum: research for issue 30)
    bias_cols = [j for j, n in enumerate(model.names) if base_name(n) in STAGE_A]
    fA, keep, uA = trimmed(model, groups, model.p0(), free=bias_cols, rounds=0)
    say(f"stage A (the IMU's biases): cost {fA.cost:.1f}")
    # stage B: the body and the friction with the biases (the scale factors and the yaw inertia,
    # which a plant still far off drives to nonsense, wait for stage C)
    first = [j for j, n in enumerate(model.names) if base_name(n) in STAGE_B]
    fB, keep, uB = trimmed(model, groups, fA.p, u0=uA, free=first, rounds=3)
    say(f"stage B ({', '.join(n for n in model.names if base_name(n) in STAGE_B and '@' not in n)}): "
        f"cost {fB.cost:.1f}")
    fB, keep, uB = trimmed(model, groups, fB.p, u0=uB, free=None, pair=True)
    say(f"stage C (everything): cost {fB.cost:.1f}, {sum(int(k.sum()) for k in keep)} windows kept")
    latencies, profiles = list(lat0), [{} for _ in logs]
    if fit_latency:
        changed = False
        for i, (lg, (st, sampled)) in enumerate(zip(logs, sts)):
            kept = np.flatnonzero(keep[i])
            pick = kept[np.linspace(0, len(kept) - 1, min(PROFILE_WINDOWS, len(kept))).round().astype(int)]
            starts = groups[i].w.starts[pick]
            one = RobotModel([lg], (), sens, fixed={**model.physical(fB.p)})
            pv = np.array([model.sensor_values(fB.p, i)[n] for n in sens])
            for d in LATENCIES:
                gd = make_group(lg, st, sampled, 0, d, periods[i])
                gd = gd.subset(np.isin(gd.w.starts, starts))
                fd = lm(one, [gd], p0=pv, tol=ROUGH)
                profiles[i][d] = fd.cost
            best = min(profiles[i], key=profiles[i].get)
            say(f"IMU latency of {lg.path}: " + ", ".join(f"{d} periods {c:.1f}" for d, c in profiles[i].items()))
            if best != groups[i].w.imu_latency:
                gb = make_group(lg, st, sampled, i, best, periods[i])
                gmax = make_group(lg, st, sampled, i, max(LATENCIES), periods[i])
                groups[i] = gb.subset(np.isin(gb.w.starts, gmax.w.starts))
                changed = True
            latencies[i] = best
        if changed:
            fB, keep, uB = trimmed(model, groups, fB.p, u0=uB, free=None, pair=True)
            say(f"stage C again at the fitted latencies: cost {fB.cost:.1f}")
    final = [g.subset(k) for g, k in zip(groups, keep)]
    f = lm(model, final, p0=fB.p, u0=[ug[k] for ug, k in zip(uB, keep)], max_iter=FINAL_ITERATIONS,
           pair=True)
    dropped = [float(t) for g, k in zip(groups, keep) for t in g.w.t0[~k]]
    info = information(f)
    cl = _Clusters(final)
    CJ, CS, G = F.covariance(info, cl)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    boot = F.bootstrap(info, cl, rng, bootstrap) if bootstrap else np.empty((0, K))
    view = _FitView(f)
    say(f"final fit on {sum(g.count for g in final)} windows ({len(dropped)} left out), {f.iterations} iterations")
    return RobotCalibration(all_names, view, info, CJ, CS, boot, G, latencies[0], profiles[0], dropped,
                            sum(g.count for g in groups), time.perf_counter() - t_start, [str(lg.path) for lg in logs],
                            [s for s, _ in sts], turns, "physical", latencies, profiles, f)


SAME_GEOMETRY = ("wheel_radius", "track")


def same_geometry(reference, log) -> None:
    """A one-line :class:`TwinError` if two logs cannot be of one robot: another wheel radius or
    track (the model's fixed geometry). The logging rate, the sensors and the commands may differ."""
    for key, a, b in (("wheel_radius", reference.model.r, log.model.r), ("track", 2 * reference.model.b,
                                                                          2 * log.model.b)):
        if abs(a - b) > 1e-9 * max(abs(a), 1.0):
            raise TwinError(f"{log.path}: another robot than {reference.path} (log.toml's {key} is {b:g}, the "
                            f"first log's {a:g}); one calibration fits logs of one robot")


def consistency(cal_a, cal_b) -> dict:
    """Whether two calibrations are of one robot, by their physical parameters: per parameter both
    fitted, z = (ln a − ln b) / √(s_a² + s_b²) with s the relative standard errors (the intervals'
    sources), and ``consistent`` when every |z| is below :data:`CONSISTENT_Z`."""

    pa, _, _ = assess(cal_a, TURN_RATE)
    pb, _, _ = assess(cal_b, TURN_RATE)
    out = {}
    for n in pa:
        if n in pb and PARAMETERS[base_name(n)].group in ("plant", "motor") and "@" not in n \
                and pa[n]["identifiable"] and pb[n]["identifiable"]:
            sa = pa[n]["standard_error"] / pa[n]["value"]
            sb = pb[n]["standard_error"] / pb[n]["value"]
            z = math.log(pa[n]["value"] / pb[n]["value"]) / math.sqrt(sa * sa + sb * sb)
            out[n] = {"calibrated": pa[n]["value"], "held_out": pb[n]["value"], "z": z}
    return {"parameters": out, "consistent": all(abs(e["z"]) < CONSISTENT_Z for e in out.values()),
            "z_limit": CONSISTENT_Z}


__all__ = ["FIT_S", "HORIZON_S", "TWIN_NAMES", "TWIN_RATES", "Group", "MIN_SECONDS", "RobotCalibration", "RobotModel", "WINDOW_S", "calibrate_robot", "consistency",
           "default_names", "information", "lm", "same_geometry", "to_twin", "trimmed", "twin_lags", "validate_physical",
           "window_periods"]


# ---- the robot in the twin -------------------------------------------------------------------------
TWIN_RATES = (200.0, 1000.0)  # Hz: the control and physics rates of the built-in scenarios (twin run's)
TWIN_NAMES = ("m_b", "l", "n_yb", "n_zb", "n_wa")  # the twin's parameters the mapping sets
TWIN_FITTED = ("m_b", "l", "n_yb", "n_wa")  # fitted to trajectories; n_zb follows from the yaw's compensation
TWIN_SCALES = np.array([1e-3, 1e-2, 1e-2, 1e-2])  # rad, rad/s, rad/s, rad/s: θ, θ̇, ψ̇, α̇ in the mapping's misfit


def _states(f: Fit, g: Group) -> np.ndarray:
    S = g.w.S0.copy()
    S[:, STATE_COLUMNS] = f.u[0][:, :4]
    return S


def to_twin(cal, params: dict | None = None, control_rate: float = TWIN_RATES[0],
            physics_rate: float = TWIN_RATES[1], horizon_s: float = 0.1) -> dict:
    """The PyBullet twin's parameters that reproduce the calibrated robot (SI values of
    :data:`TWIN_NAMES`, plus the robot's d_b and d_w), with the mapping's residual.

    The twin steps equation (1) by semi-implicit Euler with its wheel–ground damping held over a
    control period (:mod:`twin.calibrate.model`): the same physical parameters make another
    dynamical system (:func:`twin.calibrate.physical.twin_parameters`: a lagging damping acts as
    an inertia; the robot's m11 m22 − m12² is a small difference of large terms, so the pitch
    inertia moves most). The mapping simulates the calibrated robot (:mod:`twin.calibrate.
    physical`) over ``horizon_s`` from the first log's fitted window states with its drive
    (resampled to the twin's control rate, held per period), and fits the twin's stepping at
    ``control_rate`` and ``physics_rate`` to those trajectories (least squares on θ, θ̇, ψ̇, α̇ in
    units of :data:`TWIN_SCALES`), from :func:`~twin.calibrate.physical.twin_parameters`. With
    ``params`` (:func:`twin.calibrate.identify.assess`'s), a parameter not identified enters at the
    log's nominal value."""
    from scipy.optimize import least_squares


    f = cal.robot_fit
    g = f.groups[0]
    robot = g.log.model
    phys = f.model.physical(f.p)
    for n in list(phys):
        if params is not None and n in params and not params[n]["identifiable"]:
            phys[n] = f.model.base(n)
    S = g.w.S0.copy()
    S[:, STATE_COLUMNS] = f.u[0][:, :4]
    T = 1.0 / control_rate
    n = max(2, int(round(horizon_s * control_rate)))
    # the log's drive on the twin's control grid: per window, the drive at t0 + (j + ½) T
    t_rows = np.arange(g.drive.shape[1]) / g.rate
    tq = np.minimum((np.arange(n) + 0.5) * T, t_rows[-1] + (0.0 if g.sampled else 1.0 / g.rate))
    if g.sampled:
        drive = np.stack([np.stack([np.interp(tq, t_rows, g.drive[w, :, j]) for j in range(2)], axis=-1)
                          for w in range(g.count)])
    else:
        idx = np.clip(np.floor(tq * g.rate + 1e-9).astype(int), 0, g.drive.shape[1] - 1)
        drive = g.drive[:, idx]
    motor = None
    dc = None
    if g.motor is not None:
        from dataclasses import replace as dreplace

        dc = dreplace(g.log.motor, stall_torque=phys.get("stall_torque", g.motor[0]),
                      no_load_speed=phys.get("no_load_speed", g.motor[1]))
        motor = (dc.stall_torque, dc.stall_torque / dc.no_load_speed)
    rows = {k: phys[k] for k in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")}
    lags = twin_lags(g.log)
    if lags is not None:  # a log of the twin: its robot is the twin's stepping (constants' hold), as fitted
        rows["hold"] = (lags[0], lags[1], 0.0 if motor is None else motor[1])
    c = P.constants(rows, robot)
    X = P.simulate(S, drive, c, motor, control_rate)  # the robot, finely
    keep = np.all(np.isfinite(X), axis=(1, 2)) & (np.max(np.abs(X[:, :, 0]), axis=1) < 1.0)
    S, drive, X = S[keep], drive[keep], X[keep]
    start = P.twin_parameters(phys, robot, control_rate, physics_rate)
    x0 = np.log([start[k] / getattr(robot, k) for k in TWIN_FITTED])
    # the yaw: the twin's m33 must exceed the robot's by what its lagging dampings take off
    # (physical.constants' hold: 2 b²/r² (d_w (T/2 + h/2) + (d_b + c_e) h/2)); a log seldom turns
    # enough to fit that, and the trajectories could not tell n_zb from the wheels' n_wa in it
    b_r = robot.b / robot.r
    c_e = 0.0 if motor is None else float(motor[1])
    m33_robot = phys["n_zb"] + 2.0 * robot.n_wd + 2.0 * b_r * b_r * (robot.n_wa + robot.m_w * robot.r ** 2)
    m33_twin = m33_robot + (0.0 if lags is not None else
                            2.0 * b_r * b_r * (phys["d_w"] * (0.5 * T + 0.5 / physics_rate)
                                               + (phys["d_b"] + c_e) * 0.5 / physics_rate))
    if len(S) < 3:  # nothing to fit the twin to: the first-order compensation alone
        vals = {k: float(start[k]) for k in TWIN_NAMES} | {"d_b": phys["d_b"], "d_w": phys["d_w"]}
        return {"values": vals, "control_rate_hz": control_rate, "physics_rate_hz": physics_rate, "windows": 0,
                "horizon_s": n * T, "reproduces_log": None,
                "rms_misfit": {"unmapped": None, "mapped": None, "units": "no window to map on: n_wa + d_w (T/2 + h/2) "
                                                                           "only (twin.calibrate.physical.twin_parameters)"}}
    cols = [0, 1, 3, 5]

    def twin_of(x):
        v = {k: getattr(robot, k) * math.exp(xv) for k, xv in zip(TWIN_FITTED, x)}
        # a wheel is a rigid body (n_wa ≤ 2 n_wd): where the compensation needs a heavier axle inertia
        # than that, the diameter inertia grows with it; the body's yaw inertia is what makes the
        # twin's m33 the target
        n_wd = max(robot.n_wd, 0.5 * v["n_wa"] * (1.0 + 1e-9))
        v["n_zb"] = m33_twin - 2.0 * n_wd - 2.0 * b_r * b_r * (v["n_wa"] + robot.m_w * robot.r ** 2)
        return robot.replace(**v, n_wd=n_wd, d_b=phys["d_b"], d_w=phys["d_w"], n_xb=robot.n_xb * math.exp(x[2]))

    def misfit(x):
        try:  # (a trial twin may be no rigid body: a wheel's inertias breaking the triangle inequality)
            Xt = step_windows(S, drive, twin_of(x), dc, physics_rate, control_rate, drive_is_duty=dc is not None)
        except (TwinError, OverflowError):
            return np.full(X[:, 1:, cols].size, 1e6)
        r = (Xt[:, 1:, cols] - X[:, 1:, cols]) / TWIN_SCALES
        return np.where(np.isfinite(r), r, 1e6).ravel()

    def unmapped_misfit():  # the robot's own parameters in the twin
        rb = robot.replace(**{k: phys[k] for k in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")},
                           n_xb=robot.n_xb * phys["n_yb"] / robot.n_yb)
        Xt = step_windows(S, drive, rb, dc, physics_rate, control_rate, drive_is_duty=dc is not None)
        return ((Xt[:, 1:, cols] - X[:, 1:, cols]) / TWIN_SCALES).ravel()

    res = least_squares(misfit, x0, method="lm", xtol=1e-10, ftol=1e-10)
    try:
        tw = twin_of(res.x)
    except TwinError:  # the best twin is no rigid body: the first-order compensation instead
        res.x, res.fun = x0, misfit(x0)
        try:
            tw = twin_of(x0)
        except TwinError as exc:  # nor that: the twin cannot be this robot (say so; no values)
            return {"values": None, "why": str(exc), "control_rate_hz": control_rate, "physics_rate_hz": physics_rate,
                    "windows": int(len(S)), "horizon_s": n * T, "reproduces_log": None, "rms_misfit": None}
    rms0 = float(np.sqrt(np.mean(unmapped_misfit() ** 2)))
    rms = float(np.sqrt(np.mean(res.fun ** 2)))
    out = {k: float(getattr(tw, k)) for k in TWIN_NAMES + ("n_wd",)}
    out.update({"d_b": phys["d_b"], "d_w": phys["d_w"]})
    reproduces = None
    if abs(g.rate - control_rate) < 1e-9 * control_rate and not g.sampled:
        # the twin's stepping on the log itself: its readings from the fitted window states with the
        # log's drive, against the log's, as the continuous model's fit does (σ units)
        def readings_rms(rb):
            Xt = step_windows(_states(f, g), g.drive, rb, dc, physics_rate, control_rate,
                              drive_is_duty=dc is not None)
            m = f.model
            y = P.mean_readings(Xt, T, g.log.sensors.imu.position, robot.r, robot.g)
            r = m._resid(g, m.apply_sensors(y, m.sensor_values(f.p, 0)), Xt, f.u[0][:, 4:])
            return float(np.sqrt(np.mean(r * r)))

        unmapped = robot.replace(**{k: phys[k] for k in ("m_b", "l", "n_yb", "n_zb", "d_b", "d_w")},
                                 n_xb=robot.n_xb * phys["n_yb"] / robot.n_yb)
        reproduces = {"continuous model": float(np.sqrt(np.mean(f.residuals[0] ** 2))),
                      "twin, mapped": readings_rms(tw), "twin, the robot's parameters": readings_rms(unmapped),
                      "units": "RMS of the first log's readings' misfit over its fitted windows, in σ (1: the noise)"}
    return {"values": out, "control_rate_hz": control_rate, "physics_rate_hz": physics_rate,
            "windows": int(len(S)), "horizon_s": n * T, "reproduces_log": reproduces,
            "rms_misfit": {"unmapped": rms0, "mapped": rms,
                           "units": "θ in mrad, θ̇, ψ̇, α̇ in 0.01 rad/s"}}


# ---- held-out logs ---------------------------------------------------------------------------------
FIT_S = 0.05  # s of a held-out window whose readings set its start state (and the log's IMU constants)
HORIZON_S = 0.1  # s predicted open loop after it


def validate_physical(cal, logs, check_parameters: bool = True, progress=None) -> list:
    """Per held-out log: the nominal and the calibrated robot's prediction errors (as
    :func:`twin.calibrate.validate.validate`: each window's start state and the log's IMU constants
    fitted to its first :data:`FIT_S`, the next :data:`HORIZON_S` predicted open loop with the log's
    drive, by the continuous model), and with ``check_parameters`` whether the log is of the robot
    calibrated, by its parameters: the log calibrated alone, each physical parameter both
    calibrations identify compared (:func:`consistency`)."""

    say = progress or (lambda msg: None)
    f = cal.robot_fit
    ref = f.model
    phys_cal = ref.physical(f.p)
    phys_nom = {n: ref.base(n) for n in phys_cal}
    latency_s = cal.latencies[0] / f.groups[0].rate
    out = []
    for log in logs:
        same_geometry(ref.logs[0], log)
        st, sampled = log_streams(log)
        rate = float(log.control_rate)
        K, H = window_periods(rate, FIT_S), window_periods(rate, HORIZON_S)
        lat = int(round(latency_s * rate))
        full = make_group(log, st, sampled, 0, lat, K + H, stride=K)
        if full.count == 0:
            raise TwinError(f"--validate {log.path}: no {(K + H) / rate:g} s stretch with every reading")
        w = full.w
        head = full.head(K)
        res = {}
        b_r = log.model.b / log.model.r
        for name, phys in (("nominal", phys_nom), ("calibrated", phys_cal)):
            m = RobotModel([log], (), SENSORS, fixed=phys)
            fh = lm(m, [head], tol=ROUGH)
            limit = F.outlier_limit(fh.window_costs(0), head.residuals_per_window)
            S = w.S0.copy()
            S[:, STATE_COLUMNS] = fh.u[0][:, :4]
            y, X = m.truth(full, [m._phys_rows(full, fh.p)], S)
            imu = m.apply_sensors(y, m.sensor_values(fh.p, 0))
            ang = encoder_angles(X, b_r, fh.u[0][:, 4:])
            res[name] = {"imu": imu[:, K:] - w.imu[:, K:], "enc": ang[:, K + 1:] - w.angles[:, K + 1:],
                         "ok": fh.window_costs(0) <= limit, "sigma": full.sigma, "enc_sigma": full.enc_sigma}
        entry = aggregate(log, res["nominal"], res["calibrated"], K / rate, H / rate)
        if check_parameters:
            say(f"{log.path}: calibrated alone, to compare its parameters")
            names = tuple(n for n in ref.phys) + SENSORS
            alone = calibrate_robot([log], names, bootstrap=100)
            entry["same_robot"] = consistency(cal, alone)
        out.append(entry)
    return out
