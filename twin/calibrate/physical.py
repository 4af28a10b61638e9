"""The robot's continuous equations as a batched model: what ``twin calibrate`` fits by default.

Equation (1) of the paper notes, all three equations (yaw coupling included), integrated by
classical RK4 with :func:`substeps` steps per control period (at least 1 kHz), for many windows
(stretches of a log, each from its own start state) and many parameter sets at once: every
constant may be a scalar or an array of one value per row. Its discretisation is fine enough
not to leak into the parameters (the RK4 error at 1 ms is about 1e-7 of a step's change with the
fastest pole of a balancing robot near 35/s), unlike the twin's own stepping
(:mod:`twin.calibrate.model`), whose held wheel–ground damping acts like an extra wheel inertia
(:func:`twin_parameters`).

Motors, per wheel j (the torque between body and wheel):

* ideal torque sources (a log in N·m without motors): τ_j = the command;
* DC motors: τ_j = duty_j × stall torque − c_e (ψ̇_j − θ̇), c_e = stall torque / no-load speed
  = k_t k_e / R, i.e. k_t (V − k_e ω) / R with V = duty × supply voltage, inductance neglected;
  ψ̇_l,r = ψ̇ ∓ (b/r) α̇.

Commands ``held`` are constant over each period; ``sampled`` ones are values at the control
instants, joined by straight lines (RK4's stages take them at their own times).

Readings: ``mean`` IMU samples are the means over the period (:func:`mean_readings`); ``point`` samples are the values at the instant (:func:`point_readings`: the
body rates, and the specific force at the IMU's point from the accelerations).

A log whose rows are off its control instants (a hobby firmware logging one row every 30–33 ms
of a 1 kHz loop: the rows' offsets from a regular grid wander as a random walk, ~20 ms after 400
rows) is taken at its rows' own times: :func:`simulate_nodes` keeps every RK4 node with its
derivative, the drive given at every half step from the rows' true times, and :func:`at_times`
interpolates the state at any time between the nodes (cubic Hermite); a point sample is then
:func:`point_at` at its row's time, a mean sample :func:`mean_between` over its own interval
(from the IMU row before it), an encoder angle the state at its row's time.

Elementwise numpy throughout (no BLAS). SI units: rad, rad/s, N·m, kg, m, s, Hz.
"""
from __future__ import annotations

import math

import numpy as np

MIN_RATE = 1000.0  # Hz: the integration rate is at least this (a whole number of steps per control period)


def substeps(control_rate: float, min_rate: float = MIN_RATE) -> int:
    """RK4 steps per control period: the fewest that make the step rate at least ``min_rate`` Hz."""
    return max(1, int(math.ceil(min_rate / float(control_rate) - 1e-9)))


def constants(v: dict, robot) -> dict:
    """The model's constants from parameter values ``v`` (m_b, l, n_yb, n_zb, d_b, d_w: scalars or
    arrays) and the fixed geometry and wheels of ``robot`` (a :class:`twin.params.RobotParams`):
    m11, m12, m22, g_b (N·m), m33, n_bla (kg·m²), d_b, d_w (N·m·s/rad), b_r = b/r; n_xb follows
    n_yb by the robot's ratio n_xb / n_yb."""
    r, b, g = robot.r, robot.b, robot.g
    m_b, l, n_yb, n_zb = v["m_b"], v["l"], v["n_yb"], v["n_zb"]
    n_xb = n_yb * (robot.n_xb / robot.n_yb)
    n_wa = v.get("n_wa", robot.n_wa)
    b_r = b / r
    c = {"m11": (m_b + 2.0 * robot.m_w) * r * r + 2.0 * n_wa, "m12": m_b * l * r, "m22": m_b * l * l + n_yb,
         "g_b": m_b * g * l, "m33": n_zb + 2.0 * robot.n_wd + 2.0 * b_r * b_r * (n_wa + robot.m_w * r * r),
         "n_bla": m_b * l * l + n_xb - n_zb, "d_b": v["d_b"], "d_w": v["d_w"], "b_r": b_r, "e12": 0.0}
    hold = v.get("hold")
    if hold is not None:
        # the PyBullet twin's stepping as inertia (twin_lags): its joint damping d_b + c_e lags by h/2,
        # its held wheel–ground damping by T/2 + h/2; a damping c lagging by τ is an inertia −c τ
        joint, wheel = (v["d_b"] + hold[2]) * hold[1], v["d_w"] * hold[0]
        c["m11"] = c["m11"] - 2.0 * (joint + wheel)
        c["m22"] = c["m22"] - 2.0 * joint
        c["e12"] = 2.0 * joint
        c["m33"] = c["m33"] - 2.0 * b_r * b_r * (joint + wheel)
    return c


def _torques(S, ul, ur, c, motor):
    if motor is None:
        return ul, ur
    stall, c_e = motor
    rel = S[..., 3] - S[..., 1]
    dw = c["b_r"] * S[..., 5]
    return ul * stall - c_e * (rel - dw), ur * stall - c_e * (rel + dw)


def accelerations(S, tl, tr, c):
    """(θ̈, ψ̈, α̈) of equation (1) at states S (..., 6) with wheel torques tl, tr (N·m)."""
    th, thd, psd, ald = S[..., 0], S[..., 1], S[..., 3], S[..., 5]
    sn, cs = np.sin(th), np.cos(th)
    u = tl + tr
    drive = 2.0 * c["d_b"] * (thd - psd)
    r1 = c["m12"] * (thd * thd + ald * ald) * sn - 2.0 * c["d_w"] * psd + drive + u
    r2 = c["n_bla"] * ald * ald * sn * cs + c["g_b"] * sn - drive - u
    c12 = c["m12"] * cs + c["e12"]
    det = c["m11"] * c["m22"] - c12 * c12
    psdd = (c["m22"] * r1 - c12 * r2) / det
    thdd = (c["m11"] * r2 - c12 * r1) / det
    b_r = c["b_r"]
    J = c["m33"] + c["n_bla"] * sn * sn
    yaw_damping = 2.0 * b_r * b_r * (c["d_b"] + c["d_w"])
    aldd = (-2.0 * c["n_bla"] * ald * thd * sn * cs - c["m12"] * ald * psd * sn - yaw_damping * ald
            + b_r * (tr - tl)) / J
    return thdd, psdd, aldd


def _deriv(S, ul, ur, c, motor):
    tl, tr = _torques(S, ul, ur, c, motor)
    thdd, psdd, aldd = accelerations(S, tl, tr, c)
    return np.stack([S[..., 1], thdd, S[..., 3], psdd, S[..., 5], aldd], axis=-1)


def simulate(S0, drive, c: dict, motor, control_rate: float, sampled: bool = False,
             steps: int | None = None) -> np.ndarray:
    """States (B, N + 1, 6) at the control instants of B windows from ``S0`` (B, 6).

    ``drive``: (B, N, 2) per period (held), or (B, N + 1, 2) at the instants (``sampled``, joined
    by straight lines): wheel torques in N·m (``motor`` None) or duties in [−1, 1] (``motor`` =
    (stall torque N·m, c_e N·m·s/rad), scalars or (B,) arrays). ``c`` from :func:`constants`
    (entries scalars or (B,) arrays). ``steps`` RK4 steps per period (default :func:`substeps`)."""
    S0 = np.asarray(S0, dtype=float)
    drive = np.asarray(drive, dtype=float)
    B = S0.shape[0]
    N = drive.shape[1] - (1 if sampled else 0)
    k = substeps(control_rate) if steps is None else int(steps)
    h = 1.0 / (control_rate * k)
    c = {n: (np.asarray(x, dtype=float) if np.ndim(x) else float(x)) for n, x in c.items()}
    if motor is not None:
        motor = tuple(np.asarray(m, dtype=float) if np.ndim(m) else float(m) for m in motor)
    out = np.empty((B, N + 1, 6))
    out[:, 0] = S = S0
    for n in range(N):
        if sampled:
            a0, a1 = drive[:, n], drive[:, n + 1]
        else:
            a0 = a1 = drive[:, n]
        for i in range(k):
            def u(frac):
                if not sampled:
                    return a0[:, 0], a0[:, 1]
                w = (i + frac) / k
                x = a0 + w * (a1 - a0)
                return x[:, 0], x[:, 1]
            k1 = _deriv(S, *u(0.0), c, motor)
            um = u(0.5)
            k2 = _deriv(S + (0.5 * h) * k1, *um, c, motor)
            k3 = _deriv(S + (0.5 * h) * k2, *um, c, motor)
            k4 = _deriv(S + h * k3, *u(1.0), c, motor)
            S = S + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out[:, n + 1] = S
    return out


def simulate_nodes(S0, fine, c: dict, motor, h: float):
    """States and their derivatives (each (B, M + 1, 6)) at the RK4 nodes 0, h, …, M h of B windows
    from ``S0`` (B, 6), for logs whose rows are not on the control instants (a logger's jitter):
    the readings are then taken at their rows' own times, between the nodes (:func:`at_times`).

    ``fine`` (B, 2 M + 1, 2): the drive at every half step (j h / 2), as the log's rows make it at
    those times (sampled: straight lines between the rows' true times; held: from each row's time),
    each RK4 stage taking its own time's value; ``c``, ``motor`` as :func:`simulate`."""
    S0 = np.asarray(S0, dtype=float)
    fine = np.asarray(fine, dtype=float)
    M = (fine.shape[1] - 1) // 2
    c = {n: (np.asarray(x, dtype=float) if np.ndim(x) else float(x)) for n, x in c.items()}
    if motor is not None:
        motor = tuple(np.asarray(m, dtype=float) if np.ndim(m) else float(m) for m in motor)
    X = np.empty((S0.shape[0], M + 1, 6))
    D = np.empty_like(X)
    X[:, 0] = S = S0
    for i in range(M):
        u0, um, u1 = fine[:, 2 * i], fine[:, 2 * i + 1], fine[:, 2 * i + 2]
        k1 = _deriv(S, u0[:, 0], u0[:, 1], c, motor)
        k2 = _deriv(S + (0.5 * h) * k1, um[:, 0], um[:, 1], c, motor)
        k3 = _deriv(S + (0.5 * h) * k2, um[:, 0], um[:, 1], c, motor)
        k4 = _deriv(S + h * k3, u1[:, 0], u1[:, 1], c, motor)
        D[:, i] = k1
        S = S + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        X[:, i + 1] = S
    D[:, M] = _deriv(S, fine[:, 2 * M, 0], fine[:, 2 * M, 1], c, motor)
    return X, D


def at_times(X, D, h: float, tau):
    """(B, J, 6) states at times ``tau`` (B, J) s from the first node, by cubic Hermite interpolation
    between the RK4 nodes ``X`` with derivatives ``D`` (:func:`simulate_nodes`): its error, of order
    h⁴ times the fourth derivative, is far below the readings' noise at h = 1 ms."""
    M = X.shape[1] - 1
    x = np.clip(np.asarray(tau, dtype=float) / h, 0.0, float(M))
    i = np.clip(np.floor(x).astype(np.int64), 0, max(M - 1, 0))
    s = (x - i)[..., None]
    s2, s3 = s * s, s * s * s
    take = lambda A, j: np.take_along_axis(A, j[..., None], axis=1)
    j1 = np.minimum(i + 1, M)
    return ((2.0 * s3 - 3.0 * s2 + 1.0) * take(X, i) + ((s3 - 2.0 * s2 + s) * h) * take(D, i)
            + (3.0 * s2 - 2.0 * s3) * take(X, j1) + ((s3 - s2) * h) * take(D, j1))


def point_at(S, ul, ur, c: dict, motor, position, r: float, g: float):
    """(B, J, 5) true point values [gyro x, y, z, accel x, z] at states S (B, J, 6) with the drive
    (ul, ur) (B, J) acting at those instants (see :func:`point_readings`)."""
    cc = {n: (x[:, None] if np.ndim(x) else x) for n, x in c.items()}
    mm = None if motor is None else tuple(m[:, None] if np.ndim(m) else m for m in motor)
    tl, tr = _torques(S, ul, ur, cc, mm)
    thdd, psdd, aldd = accelerations(S, tl, tr, cc)
    return _specific(S, thdd, psdd, aldd, position, r, g)


def mean_between(Xa, Xb, T, position, r: float, g: float):
    """(B, J, 5) true means [gyro x, y, z, accel x, z] over intervals of lengths ``T`` (B, J) s from
    states Xa to Xb (B, J, 6) at their ends: :func:`mean_readings` for intervals of their own
    lengths (a jittered logger's), resolved at each interval's middle."""
    tha, thb, ala, alb = Xa[..., 0], Xb[..., 0], Xa[..., 4], Xb[..., 4]
    d_th = (thb - tha) / T
    d_al = (alb - ala) / T
    mid = 0.5 * (tha + thb)
    sm, cm = np.sin(mid), np.cos(mid)
    xp, zp = float(position[0]), float(position[2])

    def uw(X):
        sn, cs = np.sin(X[..., 0]), np.cos(X[..., 0])
        dx, dz = xp * cs + zp * sn, -xp * sn + zp * cs
        return r * X[..., 3] + X[..., 1] * dz, -X[..., 1] * dx, dx

    ua, wa, dxa = uw(Xa)
    ub, wb, dxb = uw(Xb)
    fx = (ub - ua) / T - d_al * d_al * 0.5 * (dxa + dxb)
    fz = (wb - wa) / T + g
    return np.stack([-d_al * sm, d_th, d_al * cm, fx * cm - fz * sm, fx * sm + fz * cm], axis=-1)


def point_readings(X, drive, c: dict, motor, position, r: float, g: float, sampled: bool):
    """(B, N, 5) [gyro x, y, z (rad/s), accel x, z (m/s²)] true point values at the instants
    1 … N of states X (B, N + 1, 6): the body rates ω = (−α̇ sin θ, θ̇, α̇ cos θ) and the specific
    force at the IMU's point p = ``position`` (body axes, from the axle), a_P − g, with the axle's
    acceleration (r ψ̈ cos θ, ·, r ψ̈ sin θ) (rolling without slip) and the rigid-body terms
    ω̇ × p + ω × (ω × p); the lateral point offset is taken as zero."""
    S = X[:, 1:]
    if sampled:
        ul, ur = drive[:, 1:, 0], drive[:, 1:, 1]
    else:
        ul, ur = drive[:, :, 0], drive[:, :, 1]
    cc = {n: (x[:, None] if np.ndim(x) else x) for n, x in c.items()}
    mm = None if motor is None else tuple(m[:, None] if np.ndim(m) else m for m in motor)
    tl, tr = _torques(S, ul, ur, cc, mm)
    thdd, psdd, aldd = accelerations(S, tl, tr, cc)
    return _specific(S, thdd, psdd, aldd, position, r, g)


def _specific(S, thdd, psdd, aldd, position, r: float, g: float):
    th, thd, psd, ald = S[..., 0], S[..., 1], S[..., 3], S[..., 5]
    sn, cs = np.sin(th), np.cos(th)
    wx, wy, wz = -ald * sn, thd, ald * cs
    ex, ey, ez = -aldd * sn - ald * thd * cs, thdd, aldd * cs - ald * thd * sn
    px, pz = float(position[0]), float(position[2])
    cx, cy, cz = wy * pz, wz * px - wx * pz, -wy * px
    ax = r * psdd * cs + ey * pz + (wy * cz - wz * cy) - g * sn
    az = r * psdd * sn - ey * px + (wx * cy - wy * cx) + g * cs
    return np.stack([wx, wy, wz, ax, az], axis=-1)


def mean_readings(X, T: float, position, r: float, g: float, at_end: bool = False):
    """(B, N, 5) true [gyro x, y, z (rad/s), accel x, z (m/s²)] means over the N periods of states
    X (B, N + 1, 6), as an IMU that integrates in its own axes reports them (a delta-angle,
    delta-velocity part): the heading-frame means of :func:`twin.calibrate.readings.imu_readings`
    (exact: differences of the rates and velocities over the period) resolved in body axes at the
    period's middle θ, which is the mean of the rotating projection to second order in the period
    (resolved at the period's end, as the twin's own IMU does, they lag by half a period: a
    forward-acceleration error of about g θ̇ T / 2, which biased the body's height by 1 %).
    ``at_end``: resolved at the period's end, as the twin's own IMU does (:mod:`twin.sensors.imu`),
    for the twin's logs."""
    th, th_d, ps_d, al = X[..., 0], X[..., 1], X[..., 3], X[..., 4]
    d_th = (th[:, 1:] - th[:, :-1]) / T
    d_al = (al[:, 1:] - al[:, :-1]) / T
    mid = 0.5 * (th[:, 1:] + th[:, :-1])
    sm, cm = np.sin(mid), np.cos(mid)
    xp, zp = float(position[0]), float(position[2])
    sn, cs = np.sin(th), np.cos(th)
    dx, dz = xp * cs + zp * sn, -xp * sn + zp * cs
    u = r * ps_d + th_d * dz
    w = -th_d * dx
    fx = (u[:, 1:] - u[:, :-1]) / T - d_al * d_al * 0.5 * (dx[:, 1:] + dx[:, :-1])
    fz = (w[:, 1:] - w[:, :-1]) / T + g
    rs, rc = (sn[:, 1:], cs[:, 1:]) if at_end else (sm, cm)
    return np.stack([-d_al * sm, d_th, d_al * cm, fx * rc - fz * rs, fx * rs + fz * rc], axis=-1)


def twin_parameters(values: dict, robot, control_rate: float, physics_rate: float) -> dict:
    """The PyBullet twin's parameters that reproduce a robot of physical ``values`` (SI).

    The twin holds the wheel–ground damping torque −d_w ψ̇_j over each control period T, taken at
    the period's start, and steps by semi-implicit Euler at h = 1 / physics rate: the torque
    lags the continuous one by T/2 + h/2 on average, −d_w (ψ̇ − ψ̈ (T/2 + h/2)), which adds
    −d_w (T/2 + h/2) ψ̈ to each wheel's inertia about its axle: the twin's wheels act lighter by
    that much. A twin whose wheels are heavier about the axle by as much behaves as the robot:
    n_wa_twin = n_wa + d_w (T/2 + h/2) (the same term accounts for the twin's yaw: the wheels'
    inertia enters the yaw inertia as (2b²/r²) n_wa, which is where the held damping's deficit
    shows as the yaw inertia a twin-model fit inflates). Returns the values with ``n_wa`` added
    (the other parameters are the robot's)."""
    lag = 0.5 / float(control_rate) + 0.5 / float(physics_rate)
    out = dict(values)
    out["n_wa"] = robot.n_wa + values["d_w"] * lag
    return out


__all__ = ["MIN_RATE", "accelerations", "at_times", "constants", "mean_between", "mean_readings", "point_at",
           "point_readings", "simulate", "simulate_nodes", "substeps", "twin_parameters"]
