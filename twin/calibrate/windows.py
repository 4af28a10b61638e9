"""A log cut into short windows for the fit: what was applied, what was read, where each starts.

The robot balances only in closed loop, so a long open-loop simulation of it diverges within
a fraction of a second whatever its parameters. The fit therefore compares the model with the
log over short windows (:data:`WINDOW_PERIODS` control periods, 0.1 s at 200 Hz), each from its
own start state, which the fit estimates with the parameters (prediction-error / multiple-
shooting identification, Ljung 1999 §7.3; Bock & Plitt 1984): over 0.1 s the open-loop error
grows by about 2.5× (the linearised Table III model's unstable pole: +9/s with the twin's DC
motors, +18/s with ideal torque sources, 6× then), which keeps it near the noise, and the controller's feedback,
which correlates the commands with the noise, acts only through the recorded commands.

:func:`streams` puts a log's readings on its control instants (the slotting of
:func:`twin.logs.replay.instants`), with the drive of each period and the EKF's replayed
estimate of the state at each instant (the windows' first guess), and keeps each reading's
row's own time (``imu_time``, ``encoder_time``): a jittered logger's rows lie up to a period
before the instant they are slotted at, and the physical model takes them there
(:func:`twin.calibrate.robot.row_timing`); :func:`cut` makes the windows for an IMU latency of
whole periods. Where the log holds the motor current (:attr:`twin.logs.format.SensorLog.channels`,
``motor_current``), :func:`streams` puts it on the instants too and :func:`cut` gives each window
its samples; a log without it gives windows without them, exactly as before. SI units: s, rad,
rad/s, m/s², A.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twin.calibrate.model import driver_duty
from twin.errors import TwinError
from twin.logs.replay import build_for, replay, schedule

WINDOW_PERIODS = 20  # control periods per window: 0.1 s at 200 Hz
FIRST_INSTANT = 1  # the windows start from the log's second control instant (see cut)
CLIP_SIGMAS = 3.0  # a reading within this many white-noise σ of its full scale counts as clipped
# IMU channels the fit compares: body-frame gyro x, y, z (rad/s) and accelerometer x, z (m/s²);
# the lateral accelerometer is left out (the model has no lateral dynamics to check it against)
IMU_CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_z")


@dataclass
class Streams:
    """A log on its control instants t_k (s), k = 0 … n−1.

    ``gyro`` (n, 3) rad/s and ``accel`` (n, 3) m/s²: the reading arriving at t_k (NaN: none or
    clipped); ``angles`` (n, 2) rad: the encoder counts × rad per count (NaN: none);
    ``drive`` (n, 2): the duty (``drive_is_duty``) or torque command (N·m) applied over
    [t_k, t_k+1); ``estimates`` (n, 6): the EKF's [θ, θ̇, ψ, ψ̇, α, α̇] at t_k; ``imu_sigma``
    (5,) the white-noise σ of :data:`IMU_CHANNELS` per sample; ``encoder_sigma`` rad, the
    quantisation's σ (one count / √12)."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    angles: np.ndarray
    drive: np.ndarray
    drive_is_duty: bool
    estimates: np.ndarray
    imu_sigma: np.ndarray
    encoder_sigma: float
    encoder_latency: int  # control periods
    control_rate: float
    # s: the true time of the row whose reading arrives at each instant (NaN: none): a logger's rows
    # may be jittered off the instants (a hobby firmware's every 30–33 ms); ``imu_prev_time`` the
    # time of the IMU row before it (where a mean sample's interval begins)
    imu_time: np.ndarray | None = None
    imu_prev_time: np.ndarray | None = None
    encoder_time: np.ndarray | None = None
    # the motor current (n, 2) A, left and right, the sample arriving at t_k (NaN: none); None: the
    # log has no such channel (or no DC motors to compare it with); its σ per sample (A) and latency
    # (control periods)
    current: np.ndarray | None = None
    current_sigma: float = math.nan
    current_latency: int = 0


@dataclass
class Windows:
    """W windows of N periods (:func:`cut`).

    ``starts`` (W,) the instants they start at; ``S0`` (W, 6) their first-guess start states;
    ``drive`` (W, N, 2); ``imu`` (W, N, 5): the reading of period j (the mean over
    [t_s+j, t_s+j+1]) in :data:`IMU_CHANNELS`; ``angles`` (W, N + 1, 2) the encoder angles at
    t_s … t_s+N; ``imu_latency`` whole periods; ``current`` (W, N, 2) A the motor current
    sampled at t_s+1 … t_s+N (the end of each period, under that period's duty), or None."""

    starts: np.ndarray
    S0: np.ndarray
    drive: np.ndarray
    imu: np.ndarray
    angles: np.ndarray
    imu_latency: int
    streams: Streams
    current: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def periods(self) -> int:
        return self.drive.shape[1]

    @property
    def t0(self) -> np.ndarray:
        """s: each window's start."""
        return self.streams.t[self.starts]

    def subset(self, keep) -> "Windows":
        keep = np.asarray(keep)
        return Windows(self.starts[keep], self.S0[keep], self.drive[keep], self.imu[keep], self.angles[keep],
                       self.imu_latency, self.streams, None if self.current is None else self.current[keep])


def streams(log, estimates=None) -> Streams:
    """The log's readings, drive and EKF estimates on its control instants.

    ``estimates`` (n, 6): the state at each instant if already known (else the EKF is replayed
    on the log, :func:`twin.logs.replay.replay`)."""
    # the readings of each instant gathered from the log's arrays by the replay's schedule (the very
    # values the estimator gets, twin.logs.replay.instants, with no Measurement object per instant)
    sched = schedule(log)
    t, n = sched.t, len(sched.t)
    commands = log.commands[sched.command]
    sens = log.sensors
    gyro = np.full((n, 3), np.nan)
    accel = np.full((n, 3), np.nan)
    angles = np.full((n, 2), np.nan)
    for out, rows, values in ((gyro, sched.gyro, log.gyro), (accel, sched.accel, log.accel)):
        on = rows >= 0
        out[on] = values[rows[on]]
    on = sched.encoders >= 0
    angles[on] = log.counts[sched.encoders[on]] * (1.0 / (log.counts_per_rev / (2.0 * math.pi)))
    dt = 1.0 / sens.imu.rate
    for arr, spec in ((gyro, sens.imu.gyro), (accel, sens.imu.accel)):
        # a clipped reading is not a measurement of the motion (the EKF's rule, estimation/ekf.py)
        rail = spec.full_scale - CLIP_SIGMAS * spec.white_sigma(dt)
        arr[np.abs(arr) >= rail] = np.nan
    if log.duty is not None:
        ci = np.searchsorted(log.duty_t, t + 1e-6 / log.control_rate, side="right") - 1
        drive, is_duty = log.duty[np.clip(ci, 0, None)], True
    else:
        drive, is_duty = commands, False
    if estimates is None:
        estimates = replay(log, build_for(log, "ekf")).estimates
    estimates = np.asarray(estimates, dtype=float)
    if estimates.shape != (n, 6):
        raise TwinError(f"estimates must have shape ({n}, 6), one state per control instant, got {estimates.shape}")
    if log.motor is not None and not is_duty:
        # N·m commands through a driver: the duty it set, from the estimated shaft speeds at each
        # update (the driver's own measurement is not in the log); the fit is then smooth in the
        # parameters (the driver's PWM rounding frozen), research for issue 30
        b_r = log.model.b / log.model.r
        th_d, ps_d, al_d = estimates[:, 1], estimates[:, 3], estimates[:, 5]
        drive = np.column_stack([driver_duty(drive[:, 0], ps_d - b_r * al_d - th_d, log.motor),
                                 driver_duty(drive[:, 1], ps_d + b_r * al_d - th_d, log.motor)])
        is_duty = True
    imu_time = np.full(n, np.nan)
    imu_prev = np.full(n, np.nan)
    enc_time = np.full(n, np.nan)
    on = sched.gyro >= 0
    imu_time[on] = log.imu_t[sched.gyro[on]]
    prev = sched.gyro[on] - 1
    imu_prev[on] = np.where(prev >= 0, log.imu_t[np.maximum(prev, 0)], np.nan)
    on = sched.encoders >= 0
    enc_time[on] = log.encoders_t[sched.encoders[on]]
    g_sig = sens.imu.gyro.white_sigma(dt)
    a_sig = sens.imu.accel.white_sigma(dt)
    res = 2.0 * math.pi / log.counts_per_rev
    rate = log.control_rate
    current, c_sig, c_lat = None, math.nan, 0
    spec = sens.spec("motor_current") if log.motor is not None and is_duty else None
    if spec is not None and "motor_current" in sched.extra:
        # the samples on their instants, weighed by the white noise and the quantiser's step (the
        # per-run offset and gain error are not fitted: at their defaults' size, 3 mA and 0.34 %,
        # they bias a torque constant by a fraction of a per cent)
        rows = sched.extra["motor_current"]
        current = np.full((n, 2), np.nan)
        on = rows >= 0
        current[on] = log.channels["motor_current"].values[rows[on]]
        c_sig = math.sqrt(spec.noise ** 2 + spec.resolution ** 2 / 12.0)
        c_lat = int(round(spec.latency * rate))
        if not c_sig > 0.0:  # a noiseless, unquantised channel: weighed as one part in 10⁶ of its range
            c_sig = 1e-6 * spec.full_scale
        rail = spec.full_scale - CLIP_SIGMAS * c_sig  # a clipped sample is no measurement of the current
        current[np.abs(current) >= rail] = np.nan
    return Streams(t, gyro, accel, angles, np.asarray(drive, dtype=float), is_duty, estimates,
                   np.array([g_sig, g_sig, g_sig, a_sig, a_sig]), res / math.sqrt(12.0),
                   int(round(sens.encoders.latency * rate)), rate, imu_time, imu_prev, enc_time,
                   current, c_sig, c_lat)


def on_rows(s: Streams, log, drive_at) -> Streams | None:
    """The log on its own rows instead of its control instants, where its IMU, encoder and command
    rows share their times and those are off the instants (a jittered logger's): slotted on a
    regular grid, such rows collide (two in one period, the earlier lost) and leave periods empty
    (a window with a reading missing is left out: a fifth of a profile-B log's windows). Row k is
    then "instant" k: its readings, ``drive_at`` (a function of times, s) at its time, the EKF's
    estimate interpolated to it; ``t`` the rows' times (s), and each reading's time its row's.
    None where the rows are on the instants or the streams' rows differ."""
    t = np.asarray(log.imu_t, dtype=float)
    if (len(t) < 2 or len(log.encoders_t) != len(t) or len(log.commands_t) != len(t)
            or not np.array_equal(t, log.encoders_t) or not np.array_equal(t, log.commands_t)
            or not np.all(np.diff(t) > 0.0)):
        return None
    rate = float(s.control_rate)
    k = np.round((t - s.t[0]) * rate)
    if not np.max(np.abs(t - (s.t[0] + k / rate))) > 1e-6:
        return None  # on the instants: the slotting is exact
    keep = (t >= s.t[0] - 1e-9) & (t <= s.t[-1] + 1e-9)
    rows = np.flatnonzero(keep)
    t = t[rows]
    gyro, accel = np.array(log.gyro[rows], dtype=float), np.array(log.accel[rows], dtype=float)
    sens = log.sensors
    dt = 1.0 / sens.imu.rate
    for arr, spec in ((gyro, sens.imu.gyro), (accel, sens.imu.accel)):
        rail = spec.full_scale - CLIP_SIGMAS * spec.white_sigma(dt)
        arr[np.abs(arr) >= rail] = np.nan
    angles = np.where(log.has_counts[rows, None], log.counts[rows] * (2.0 * math.pi / log.counts_per_rev), np.nan)
    est = np.column_stack([np.interp(t, s.t, s.estimates[:, j]) for j in range(6)])
    prev = np.concatenate([[np.nan], t[:-1]])
    return Streams(t, gyro, accel, angles, np.asarray(drive_at(t), dtype=float), s.drive_is_duty, est,
                   s.imu_sigma, s.encoder_sigma, s.encoder_latency, rate, t.copy(), prev, t.copy())


def cut(s: Streams, imu_latency: int, periods: int = WINDOW_PERIODS, stride: int | None = None) -> Windows:
    """Windows of ``periods`` control periods with every reading present, one starting every
    ``stride`` periods (default ``periods``: side by side, not overlapping).

    The IMU sample of period [t_j, t_j+1] is the one arriving at t_{j+1+imu_latency} (the
    twin's IMU reports the mean over the period that ends at its sample instant,
    :mod:`twin.sensors.imu`); the encoders' angle at t_j arrives at t_{j+encoder_latency}.
    A window with a reading missing or clipped is left out. The log's first period is not used:
    its reading is the mean over an interval that began before the log's first instant (for the
    twin, the release: the first period's gyro reading misfits by 10 σ whatever the plant)."""
    n = len(s.t)
    d, de = int(imu_latency), s.encoder_latency
    last = n - 1 - max(periods + d, periods + de)
    starts = np.arange(FIRST_INSTANT, last + 1, periods if stride is None else int(stride))
    cur = None if s.current is None else np.empty((0, periods, 2))
    if len(starts) == 0:
        return Windows(starts, np.empty((0, 6)), np.empty((0, periods, 2)), np.empty((0, periods, 5)),
                       np.empty((0, periods + 1, 2)), d, s, cur)
    j = starts[:, None] + np.arange(periods)[None, :]
    imu = np.concatenate([s.gyro[j + 1 + d], s.accel[j + 1 + d][..., [0, 2]]], axis=-1)
    je = starts[:, None] + np.arange(periods + 1)[None, :] + de
    angles = s.angles[je]
    drive = s.drive[j]
    ok = np.isfinite(imu).all(axis=(1, 2)) & np.isfinite(angles).all(axis=(1, 2)) & np.isfinite(drive).all(axis=(1, 2))
    ok &= np.isfinite(s.estimates[starts]).all(axis=1)
    if s.current is not None:  # the current sampled at the end of each period (its duty's), dc periods late
        jc = j + 1 + s.current_latency
        cur = s.current[np.minimum(jc, n - 1)]
        ok &= np.isfinite(cur).all(axis=(1, 2)) & (jc[:, -1] < n)
    keep = np.flatnonzero(ok)
    return Windows(starts[keep], s.estimates[starts[keep]].copy(), drive[keep], imu[keep], angles[keep], d, s,
                   None if cur is None else cur[keep])


__all__ = ["CLIP_SIGMAS", "IMU_CHANNELS", "WINDOW_PERIODS", "Streams", "Windows", "cut", "on_rows", "streams"]
