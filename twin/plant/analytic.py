"""Full nonlinear dynamics of the robot, paper equation (1), as ODE right-hand sides.

State (8,), SI units::

    x = [θ (rad), θ̇ (rad/s), ψ (rad), ψ̇ (rad/s), α (rad), α̇ (rad/s), X (m), Y (m)]

θ is the body pitch (0 upright, positive leaning towards +ψ travel), ψ = (ψl+ψr)/2 the
mean wheel rotation angle relative to the vertical, α the heading (positive turning
left, i.e. the right wheel travels further), (X, Y) the axle midpoint in the plane,
found by rolling without slip: Ẋ = r ψ̇ cos α, Ẏ = r ψ̇ sin α. The travelled distance is
p = r ψ.

Inputs: u = [ul, ur], the left and right motor torques in N·m (each acting between body
and wheel), and optionally τ = [τ1, τ2, τ3], the lumped disturbances of equation (1) in
N·m.
"""
from __future__ import annotations

import math

import numpy as np

from twin.params import RobotParams

STATE_NAMES = ("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot", "x", "y")
STATE_UNITS = ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s", "m", "m")
THETA, THETA_DOT, PSI, PSI_DOT, ALPHA, ALPHA_DOT, X, Y = range(8)
NO_TAU = (0.0, 0.0, 0.0)  # N·m: no external torques τ1..τ3


def dynamics(t: float, x, u, params: RobotParams, tau=None) -> np.ndarray:
    """ẋ = f(t, x, u, τ) of equation (1) plus planar kinematics.

    Parameters
    ----------
    t : float
        Time in s (unused: the plant is time-invariant; kept for scipy's signature).
    x : array_like, shape (8,)
        State, see the module docstring.
    u : array_like, shape (2,)
        Motor torques [ul, ur] in N·m.
    params : RobotParams
        Physical parameters.
    tau : array_like, shape (3,), optional
        Disturbances [τ1, τ2, τ3] in N·m added to the three equations.

    Returns
    -------
    numpy.ndarray, shape (8,)
        Time derivative of the state.

    Use with scipy: ``solve_ivp(lambda t, x: dynamics(t, x, u, p), (0, T), x0)``.
    """
    return np.array(rhs(x, u[0], u[1], params, NO_TAU if tau is None else tau))


def _accelerations(theta_d, psi_d, alpha_d, s, c, ul, ur, t1, t2, t3, p: RobotParams):
    """(θ̈, ψ̈, α̈) of equation (1), from the rates, s = sin θ, c = cos θ, the wheel torques and the
    external torques τ1..τ3: floats (:func:`rhs`) or arrays of rows (:func:`rhs_batch`), the same
    operations in the same order either way."""
    m11, m12, m22, n_bla = p.m11, p.m12, p.m22, p.n_bla
    drive = 2.0 * p.d_b * (theta_d - psi_d)
    u = ul + ur
    rhs1 = m12 * (theta_d * theta_d + alpha_d * alpha_d) * s - 2.0 * p.d_w * psi_d + drive + u + t1
    rhs2 = n_bla * alpha_d * alpha_d * s * c + p.g_b * s - drive - u + t2
    det = m11 * m22 - (m12 * c) ** 2
    psi_dd = (m22 * rhs1 - m12 * c * rhs2) / det
    theta_dd = (m11 * rhs2 - m12 * c * rhs1) / det
    yaw = (
        -2.0 * n_bla * alpha_d * theta_d * s * c
        - m12 * alpha_d * psi_d * s
        - p.yaw_damping * alpha_d
        + (p.b / p.r) * (ur - ul)
        + t3
    )
    return theta_dd, psi_dd, yaw / (p.m33 + n_bla * s * s)


def rhs(x, ul: float, ur: float, p: RobotParams, tau) -> tuple:
    """dx/dt of the first six states [θ, θ̇, ψ, ψ̇, α, α̇] (and the planar x, y rates) as a tuple:
    equation (1) with wheel torques ``ul``, ``ur`` (N·m) and external torques ``tau`` (τ1..τ3)."""
    theta, theta_d, _psi, psi_d, alpha, alpha_d = x[0], x[1], x[2], x[3], x[4], x[5]
    theta_dd, psi_dd, alpha_dd = _accelerations(theta_d, psi_d, alpha_d, math.sin(theta), math.cos(theta), ul, ur,
                                                tau[0], tau[1], tau[2], p)
    v = p.r * psi_d
    return (theta_d, theta_dd, psi_d, psi_dd, alpha_d, alpha_dd, v * math.cos(alpha), v * math.sin(alpha))


def balance_dynamics(t: float, x, u: float, params: RobotParams, tau=None) -> np.ndarray:
    """The balance subsystem x' = f(x) + g(x) u used for the TS model (yaw at rest).

    ``x`` = [θ, θ̇, ψ, ψ̇] (rad, rad/s, rad, rad/s); ``u`` = ul + ur, total torque in N·m;
    ``tau`` = [τ1, τ2] in N·m. Returns shape (4,).
    """
    full = (x[0], x[1], x[2], x[3], 0.0, 0.0)
    d = rhs(full, 0.5 * u, 0.5 * u, params, (0.0, 0.0, 0.0) if tau is None else (tau[0], tau[1], 0.0))
    return np.array(d[:4])


def rk4_step(x: np.ndarray, ul: float, ur: float, params: RobotParams, dt: float, tau=None) -> np.ndarray:
    """One classical Runge–Kutta step of length ``dt`` (s) with inputs held constant."""
    tau = NO_TAU if tau is None else tau
    k1 = np.array(rhs(x, ul, ur, params, tau))
    k2 = np.array(rhs(x + 0.5 * dt * k1, ul, ur, params, tau))
    k3 = np.array(rhs(x + 0.5 * dt * k2, ul, ur, params, tau))
    k4 = np.array(rhs(x + dt * k3, ul, ur, params, tau))
    return x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def wheel_angles(x, params: RobotParams) -> tuple[float, float]:
    """(ψl, ψr) in rad from ψ and α, assuming rolling without slip from α = 0."""
    half = params.b / params.r * x[ALPHA]
    return x[PSI] - half, x[PSI] + half


def rhs_batch(S, tau_l, tau_r, p: RobotParams, tau=None) -> np.ndarray:
    """:func:`rhs` for many states at once: d/dt of [θ, θ̇, ψ, ψ̇, α, α̇] row by row.

    Parameters
    ----------
    S : numpy.ndarray, shape (W, 6) (or (W, 8): the planar x, y columns are ignored)
        States [θ (rad), θ̇ (rad/s), ψ (rad), ψ̇ (rad/s), α (rad), α̇ (rad/s)].
    tau_l, tau_r : float or numpy.ndarray, shape (W,)
        Left and right wheel torques in N·m (each between body and wheel), per row.
    p : RobotParams
        Physical parameters.
    tau : array_like, shape (3,) or (W, 3), optional
        External torques τ1..τ3 of equation (1) in N·m (one set for all rows, or per row).

    Returns
    -------
    numpy.ndarray, shape (W, 6)
        [θ̇, θ̈, ψ̇, ψ̈, α̇, α̈] per row (rad/s, rad/s²).

    Only elementwise numpy arithmetic, in the order :func:`rhs` does it, with sin θ and cos θ
    from :mod:`math` (libm, as :func:`rhs`; numpy's own may take SIMD paths that differ by an
    ulp between CPUs): each row equals ``rhs`` on that row bit for bit, and no BLAS kernel is
    involved.
    """
    S = np.asarray(S, dtype=float)
    theta, theta_d, psi_d, alpha_d = S[:, 0], S[:, 1], S[:, 3], S[:, 5]
    if tau is None:
        t1 = t2 = t3 = 0.0
    else:
        tau = np.asarray(tau, dtype=float)
        t1, t2, t3 = (tau[0], tau[1], tau[2]) if tau.ndim == 1 else (tau[:, 0], tau[:, 1], tau[:, 2])
    rows = theta.tolist()
    s = np.fromiter(map(math.sin, rows), float, len(rows))
    c = np.fromiter(map(math.cos, rows), float, len(rows))
    theta_dd, psi_dd, alpha_dd = _accelerations(theta_d, psi_d, alpha_d, s, c, tau_l, tau_r, t1, t2, t3, p)
    out = np.empty((S.shape[0], 6))
    out[:, 0], out[:, 1], out[:, 2] = theta_d, theta_dd, psi_d
    out[:, 3], out[:, 4], out[:, 5] = psi_dd, alpha_d, alpha_dd
    return out

try:  # the compiled batch stepping of twin/plant/_fastpath.c (optional: rhs_batch by RK4 does the same)
    from twin.plant._fastpath import windows as compiled_windows
except ImportError:  # pragma: no cover - the kernel did not build (or is an older one without it)
    compiled_windows = None
