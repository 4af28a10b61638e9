"""Sign checks a user runs on their own log: do the sensors agree with each other about the axes?

:func:`sign_checks` compares what two sensors say about one motion, with no model of the robot
and no estimator, on the log's readings in body axes (a version-2 log's IMU orientation applied,
:attr:`twin.logs.format.SensorLog.imu_rotation`). Each check is ``pass``, ``warn`` (the two
disagree: a sign, an axis, a unit or a mounting is likely wrong) or ``skip`` (the log holds too
little of the motion to tell), with the figures it was judged on and one line of text:

``gravity_on_z``
    The accelerometer at rest at the start (the rows before the gyro first reaches
    :data:`STILL_RATE`, at most the first 0.1 s; a log that starts in motion: its first quiet
    stretch, below): its mean must be g within :data:`G_TOLERANCE` and lie in the body's x–z
    plane (a body on its wheels does not roll): ``|f_y| <= G_TOLERANCE · g``. A y component
    is a roll or yaw of the IMU that log.toml's ``[imu] orientation`` does not say. Both
    tolerances widen by 3 σ/√n for the accelerometer's white noise σ in the n rows averaged.
``gyro_pitch_vs_accel_tilt``
    The gyro's pitch rate (y) integrated from the start at rest to each quiet stretch within
    :data:`HORIZON` s, against the accelerometer's tilt change from the start to it; the
    slope of the one on the other over every quiet stretch (least squares through zero) must
    lie in [0.8, 1.25]. A quiet stretch is a :data:`WINDOW` s window whose specific force is g
    within 2 %, whose mean |pitch rate| is below :data:`QUIET_RATE` and whose wheels
    accelerate less than :data:`QUIET_ACCEL` g (the encoders): without acceleration the
    accelerometer gives the tilt, θ = atan2(−f_x, f_z). (A balancing robot leans to
    accelerate, and its accelerometer then reads nearly upright: without the last test an
    independent simulator's drives gave a false warning.) The gyro's bias is its mean at rest.
    Where the gyro clipped in between, only the sign is judged (the integral falls short).
    Needs a tilt change of at least :data:`MIN_TILT` rad (a robot that stands up, or is let go
    from a tilt).
``gyro_yaw_vs_encoders``
    The gyro's yaw rate (z) integrated against the heading the encoders give, α = r (q_r −
    q_l) / (2 b), over :data:`SPAN` s steps with a turn of more than five counts: the slope
    of one on the other (least squares through zero) must lie in [0.8, 1.25]. It checks
    gyro_z's sign, which encoder is left, and the track. Needs a turn of at least
    :data:`MIN_TURN` rad in all.
``encoders_vs_commands``
    Each wheel's speed relative to the body (its encoder) against its command, both averaged
    over :data:`SPAN` s steps: the correlation must be positive (above :data:`MIN_CORRELATION`)
    for each wheel. A forward command drives the wheel forward: torque, duty and volts alike
    (a balancing robot's commands follow its wheels' speed at these time scales). Needs the
    wheels to move.

Mean sampling (each row the mean over the interval since the previous row) integrates exactly
as rate × interval; point samples by the trapezoid.
"""
from __future__ import annotations

import math

import numpy as np

STILL_RATE = 0.1  # rad/s: every gyro axis below this at the start counts as at rest
G_TOLERANCE = 0.05  # of g: the accelerometer's norm at rest, and its y component
WINDOW = 0.1  # s: the quiet windows of gyro_pitch_vs_accel_tilt
QUIET_RATE = 0.05  # rad/s: a quiet window's mean |pitch rate|
QUIET_G = 0.02  # of g: a quiet window's specific force is g within this
QUIET_ACCEL = 0.02  # g: a quiet window's wheels accelerate less than this (a lean of at most 0.02 rad)
HORIZON = 10.0  # s: the quiet windows compared with the start lie within this of it
MIN_TILT = 0.1  # rad: the tilt change the pitch check needs
SPAN = 0.25  # s: the steps of the yaw and the encoder checks
MIN_TURN = 0.2  # rad: the turning (sum of |Δα|) the yaw check needs
MIN_CORRELATION = 0.3  # the correlation of a wheel's speed and command that passes (below −0.3: warn)
RATIO = (0.8, 1.25)  # a ratio or slope that passes


def _correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson's correlation of x and y, its sums exactly rounded (the same bits on every CPU)."""
    dx, dy = x - math.fsum(x) / len(x), y - math.fsum(y) / len(y)
    return math.fsum(dx * dy) / math.sqrt(math.fsum(dx * dx) * math.fsum(dy * dy))


def _check(status: str, text: str, **figures) -> dict:
    return {"status": status, "text": text, "figures": figures}


def sign_checks(log, accel_sigma: float | None = None) -> dict:
    """The checks of the module docstring on ``log`` (a :class:`twin.logs.format.SensorLog`):
    ``{name: {"status": "pass" | "warn" | "skip", "text": one line, "figures": {...}}}``, in SI
    units (rad, rad/s, m/s²; ratios and correlations dimensionless).

    ``accel_sigma`` (m/s²): the accelerometer's white noise in one sample, which widens the
    gravity check's tolerance by 3 σ/√n over n rows (a log of one noisy row at rest is not a
    tilted IMU); default the log's own figure (``log.sensors``)."""
    both = np.flatnonzero(np.isfinite(log.gyro).all(axis=1) & np.isfinite(log.accel).all(axis=1))
    g = float(log.model.g)
    out = {}
    if len(both) < 2:
        reason = "fewer than 2 IMU rows with both a gyro and an accelerometer reading"
        for name in ("gravity_on_z", "gyro_pitch_vs_accel_tilt", "gyro_yaw_vs_encoders"):
            out[name] = _check("skip", f"{name}: skipped: {reason}")
        out["encoders_vs_commands"] = _encoders_vs_commands(log)
        return out
    # the start of the log, as far as the pitch check looks (a long log's rows are not copied)
    t_all = log.imu_t[both]
    head = both[:int(np.searchsorted(t_all, t_all[0] + HORIZON + 2.0 * WINDOW, side="right"))]
    t, w, a = log.imu_t[head], log.gyro[head], log.accel[head]
    first = int(np.searchsorted(t, t[0] + 0.1, side="right"))
    moving = np.flatnonzero(np.abs(w[:first]).max(axis=1) >= STILL_RATE)
    rest = int(moving[0]) if moving.size else first  # the rows at rest at the start (0: it starts moving)
    dt0 = 1.0 / log.sensors.imu.rate
    integral = _integral(t, w, log.sampling, dt0)
    quiet = _Quiet(log, t, w, a, integral, rest, g)
    if accel_sigma is None:
        accel_sigma = log.sensors.imu.accel.white_sigma(1.0 / log.sensors.imu.rate)
    out["gravity_on_z"] = _gravity(a[:rest], g, rest, quiet, float(accel_sigma))
    out["gyro_pitch_vs_accel_tilt"] = _pitch(log, t, w, a, integral, rest, quiet)
    bias = float(w[:rest, 2].mean()) if rest else 0.0
    z = _integral(t_all, log.gyro[both, 2:3], log.sampling, dt0)[:, 0]
    out["gyro_yaw_vs_encoders"] = _yaw(log, t_all, z - bias * (t_all - t_all[0] + dt0))
    out["encoders_vs_commands"] = _encoders_vs_commands(log)
    return out


def _integral(t, w, sampling: str, dt0: float) -> np.ndarray:
    """(n, 3) rad: the rates integrated from before the first row to each row's t."""
    dt = np.diff(t, prepend=t[0] - dt0)
    if sampling == "point":  # the trapezoid between samples (the first row: its own rate over dt0)
        mid = np.vstack([w[:1], 0.5 * (w[1:] + w[:-1])])
        return np.cumsum(mid * dt[:, None], axis=0)
    return np.cumsum(w * dt[:, None], axis=0)  # a mean over its interval × the interval: exact


def _windows(t: np.ndarray, start: float, width: float):
    """(window index of each row from ``start`` on (−1 before it), number of windows)."""
    n = int(max(0.0, t[-1] - start) // width)
    idx = np.floor((t - start) / width).astype(np.int64)
    idx[(t < start) | (idx >= n)] = -1
    return idx, n


def _means(idx: np.ndarray, n: int, x: np.ndarray):
    keep = idx >= 0
    count = np.bincount(idx[keep], minlength=n).astype(float)
    cols = [np.bincount(idx[keep], weights=x[keep, j], minlength=n) for j in range(x.shape[1])]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.column_stack(cols) / count[:, None], count


class _Quiet:
    """The :data:`WINDOW` s windows of the log's start (up to :data:`HORIZON` s after the rows at
    rest, or after its first row) and which are quiet: the specific force g within
    :data:`QUIET_G`, the mean |pitch rate| below :data:`QUIET_RATE` (the bias at rest removed),
    and the wheels' acceleration (the encoders' mean, second difference over three windows) below
    :data:`QUIET_ACCEL` g. The last matters on a balancing robot: to accelerate it leans, and
    its accelerometer then reads nearly upright (f_x = a cos θ − g sin θ ≈ 0)."""

    def __init__(self, log, t, w, a, integral, rest: int, g: float):
        self.bias = w[:rest].mean(axis=0) if rest else np.zeros(3)
        start = float(t[rest - 1]) if rest else float(t[0])
        idx, n = _windows(t, start, WINDOW)
        self.n = n
        if n < 1:
            self.q = np.empty(0, dtype=np.int64)
            return
        self.f, count = _means(idx, n, a)
        self.count = count
        self.i, _ = _means(idx, n, integral)
        self.t = _means(idx, n, t[:, None])[0][:, 0]
        rate = _means(idx, n, np.abs(w[:, 1:2] - self.bias[1]))[0][:, 0]
        quiet = (count > 0) & (np.abs(np.linalg.norm(self.f, axis=1) - g) < QUIET_G * g) & (rate < QUIET_RATE)
        et, qw = _encoder_angles(log)
        self.wheels = len(et) >= 2
        if self.wheels:  # the wheels' (mean) acceleration relative to the body, m/s² at the rim
            edges = start + WINDOW * np.arange(n + 1)
            travel = np.interp(edges, et, 0.5 * (qw[:, 0] + qw[:, 1])) * float(log.model.r)
            v = np.diff(travel) / WINDOW
            acc = np.abs(np.gradient(v, WINDOW)) if n > 1 else np.zeros(n)
            quiet &= (acc < QUIET_ACCEL * g) & (edges[:-1] >= et[0]) & (edges[1:] <= et[-1])
        self.q = np.flatnonzero(quiet)


def _gravity(a: np.ndarray, g: float, rest: int, quiet: _Quiet, sigma: float) -> dict:
    if rest:
        f, where, n = a.mean(axis=0), f"at rest ({rest} rows)", rest
    elif quiet.q.size:  # a log that starts in motion: its first quiet stretch
        f, where = quiet.f[quiet.q[0]], f"over the first quiet {WINDOW:g} s (at {quiet.t[quiet.q[0]]:.3g} s)"
        n = max(1, int(quiet.count[quiet.q[0]]))
    else:
        return _check("skip", "gravity_on_z: skipped: the log starts in motion and holds no quiet stretch")
    norm = float(np.linalg.norm(f))
    figs = {"specific_force_m_s2": [float(v) for v in f], "norm_m_s2": norm,
            "tilt_rad": float(math.atan2(-f[0], f[2])), "y_share": float(f[1] / norm) if norm else None,
            "rest_rows": rest}
    # the mean of n rows still carries the noise's σ/√n: a tolerance below 3 of those would
    # call noise a tilted mounting
    tol = G_TOLERANCE * g + 3.0 * sigma / math.sqrt(n)
    figs["tolerance_m_s2"] = tol
    if abs(norm - g) > tol:
        return _check("warn", f"gravity_on_z: warn: the accelerometer reads {norm:.3g} m/s² {where}, "
                              f"{abs(norm - g) / g:.1%} off g (a scale or a unit?)", **figs)
    if abs(f[1]) > tol:
        return _check("warn", f"gravity_on_z: warn: gravity has {f[1]:+.3g} m/s² on y {where} "
                              f"({math.degrees(math.asin(max(-1.0, min(1.0, f[1] / norm)))):+.1f}°): a roll or yaw "
                              f"of the IMU that [imu] orientation does not say?", **figs)
    return _check("pass", f"gravity_on_z: pass: {norm:.4g} m/s² {where}, in the x–z plane (y {f[1]:+.2g} m/s²), "
                          f"tilt {figs['tilt_rad']:+.3g} rad", **figs)


def _pitch(log, t, w, a, integral, rest: int, quiet: _Quiet) -> dict:
    name = "gyro_pitch_vs_accel_tilt"
    if quiet.n < 1:
        return _check("skip", f"{name}: skipped: the log is shorter than one {WINDOW:g} s window")
    q, bias = quiet.q, quiet.bias
    if rest:
        f0, i0, t0 = a[:rest].mean(axis=0), integral[:rest].mean(axis=0), float(t[:rest].mean())
    else:  # no rest at the start: the first quiet window is the reference, the bias unknown (0)
        if not q.size:
            return _check("skip", f"{name}: skipped: no quiet {WINDOW:g} s stretch (g within {QUIET_G:.0%}, pitch rate "
                                  f"below {QUIET_RATE:g} rad/s, the wheels' acceleration below {QUIET_ACCEL:g} g)")
        f0, i0, t0 = quiet.f[q[0]], quiet.i[q[0]], float(quiet.t[q[0]])
        q = q[1:]
    q = q[quiet.t[q] - t0 <= HORIZON]
    tilt0 = math.atan2(-f0[0], f0[2])
    if not q.size:
        return _check("skip", f"{name}: skipped: no quiet {WINDOW:g} s stretch within {HORIZON:g} s of the start")
    fm, im, tm = quiet.f, quiet.i, quiet.t
    d_acc = np.arctan2(-fm[q, 0], fm[q, 2]) - tilt0  # rad: each quiet stretch's tilt change from the start
    d_gyro = im[q, 1] - i0[1] - bias[1] * (tm[q] - t0)  # rad: the gyro's integral over the same
    big = float(np.max(np.abs(d_acc)))
    figs = {"from_s": t0, "quiet_stretches": int(q.size), "largest_tilt_change_rad": big,
            "gyro_bias_rad_s": float(bias[1]) if rest else None, "wheel_acceleration_judged": quiet.wheels}
    if big < MIN_TILT:
        return _check("skip", f"{name}: skipped: the tilt changes by {big:.3g} rad at most between quiet stretches "
                              f"(at least {MIN_TILT:g} rad tells the sign)", **figs)
    # least squares through zero over every quiet stretch: one whose specific force holds an
    # acceleration as well as gravity weighs no more than the others
    slope = math.fsum(d_acc * d_gyro) / math.fsum(d_acc * d_acc)  # exactly rounded: the same bits on every CPU
    figs["slope"] = slope
    spec = log.sensors.imu.gyro
    between = (t > t0) & (t <= tm[q[-1]])
    rail = spec.full_scale - 3.0 * spec.white_sigma(1.0 / log.sensors.imu.rate)
    clipped = bool(np.any(np.abs(w[between, 1]) >= rail))
    figs["gyro_clipped"] = clipped
    said = (f"gyro_y integrated from {t0:.3g} s against the accelerometer's tilt change at {q.size} quiet stretches "
            f"(up to {big:.3g} rad): slope {slope:.3g}")
    if slope < 0:
        return _check("warn", f"{name}: warn: {said}: opposite signs (gyro_y's sign, or the mounting?)", **figs)
    if clipped:
        status = "pass" if slope > 0.5 else "warn"
        return _check(status, f"{name}: {status}: {said}; the gyro clipped in between, so only the sign is judged",
                      **figs)
    if RATIO[0] <= slope <= RATIO[1]:
        return _check("pass", f"{name}: pass: {said}", **figs)
    return _check("warn", f"{name}: warn: {said}: outside [{RATIO[0]:g}, {RATIO[1]:g}] (a unit, deg/s for rad/s, or "
                          f"an axis?)", **figs)


def _encoder_angles(log):
    """(t (m,) s, wheel angles relative to the body (m, 2) rad) of the rows with counts."""
    res = 2.0 * math.pi / log.counts_per_rev
    has = log.has_counts
    return log.encoders_t[has], log.counts[has] * res


def _yaw(log, t, z) -> dict:
    """``z`` (n,) rad: the gyro's yaw rate integrated to each IMU row's ``t``, its bias at rest removed."""
    name = "gyro_yaw_vs_encoders"
    et, q = _encoder_angles(log)
    if len(et) < 2:
        return _check("skip", f"{name}: skipped: fewer than 2 encoder rows")
    lo, hi = max(t[0], et[0]), min(t[-1], et[-1])
    edges = np.arange(lo, hi, SPAN)
    if len(edges) < 3:
        return _check("skip", f"{name}: skipped: less than {2 * SPAN:g} s of IMU and encoders together")
    r, b = float(log.model.r), float(log.model.b)
    alpha = np.interp(edges, et, r * (q[:, 1] - q[:, 0]) / (2.0 * b))
    gyro = np.interp(edges, t, z)
    da, dg = np.diff(alpha), np.diff(gyro)
    one = 5.0 * r * (2.0 * math.pi / log.counts_per_rev) / (2.0 * b)  # five counts of turning
    m = np.abs(da) > one
    turn = float(np.abs(da[m]).sum())
    figs = {"turn_rad": turn, "steps": int(m.sum()), "step_s": SPAN}
    if turn < MIN_TURN:
        return _check("skip", f"{name}: skipped: the encoders turn by {turn:.3g} rad in all (at least {MIN_TURN:g} rad "
                              f"tells the sign)", **figs)
    slope = math.fsum(da[m] * dg[m]) / math.fsum(da[m] * da[m])
    figs["slope"] = slope
    said = f"gyro_z against the encoders' heading over {turn:.3g} rad of turning: slope {slope:.3g}"
    if slope < 0:
        return _check("warn", f"{name}: warn: {said}: opposite signs (gyro_z's sign, or left and right encoders "
                              f"swapped?)", **figs)
    if RATIO[0] <= slope <= RATIO[1]:
        return _check("pass", f"{name}: pass: {said}", **figs)
    return _check("warn", f"{name}: warn: {said}: outside [{RATIO[0]:g}, {RATIO[1]:g}] (the track, the wheel radius, "
                          f"or a unit?)", **figs)


def _encoders_vs_commands(log) -> dict:
    name = "encoders_vs_commands"
    et, q = _encoder_angles(log)
    ct, u = log.commands_t, log.commands
    lo, hi = max(ct[0], et[0] if len(et) else math.inf), min(ct[-1], et[-1] if len(et) else -math.inf)
    edges = np.arange(lo, hi, SPAN) if hi > lo else np.empty(0)
    if len(edges) < 4:
        return _check("skip", f"{name}: skipped: less than {3 * SPAN:g} s of encoders and commands together")
    speed = np.diff(np.column_stack([np.interp(edges, et, q[:, j]) for j in range(2)]), axis=0) / SPAN
    # the commands' mean over each step (held from each row, as the format's default says)
    tt = np.maximum.accumulate(ct)
    cum = np.vstack([np.zeros((1, 2)), np.cumsum(u[:-1] * np.diff(tt)[:, None], axis=0)])
    i = np.clip(np.searchsorted(tt, edges, side="right") - 1, 0, len(tt) - 1)
    at = cum[i] + u[i] * (edges - tt[i])[:, None]
    mean_u = np.diff(at, axis=0) / SPAN
    res = 2.0 * math.pi / log.counts_per_rev
    moving = speed.std(axis=0) > 2.0 * res / SPAN  # more than two counts a step, typically
    figs = {"step_s": SPAN, "correlation_left": None, "correlation_right": None}
    rho = []
    for j, side in enumerate(("left", "right")):
        if moving[j] and mean_u[:, j].std() > 0:
            c = _correlation(speed[:, j], mean_u[:, j])
            figs[f"correlation_{side}"] = c
            rho.append(c)
    if len(rho) < 2:
        return _check("skip", f"{name}: skipped: the wheels hardly move, or a command is constant", **figs)
    said = f"each wheel's speed against its command over {SPAN:g} s steps: correlation left {rho[0]:+.2f}, " \
           f"right {rho[1]:+.2f}"
    if min(rho) < -MIN_CORRELATION:
        which = "both wheels turn" if max(rho) < -MIN_CORRELATION else ("the left wheel turns" if rho[0] < rho[1]
                                                                        else "the right wheel turns")
        return _check("warn", f"{name}: warn: {said}: {which} against the command (an encoder's or a "
                              f"command's sign, or left and right swapped?)", **figs)
    if min(rho) > MIN_CORRELATION:
        return _check("pass", f"{name}: pass: {said}", **figs)
    return _check("skip", f"{name}: skipped: {said}: too weak to tell (above {MIN_CORRELATION:g} passes)", **figs)


__all__ = ["sign_checks"]
