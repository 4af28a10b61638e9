"""The plant's time-stepping as a batched model, for fitting its parameters to logs.

:func:`step_windows` reproduces how a plant advances one control period, for W windows
(stretches of a log, each from its own start state) at once:

``plant="bullet"`` — the PyBullet twin (:meth:`twin.plant.bullet.BulletTwin.step`)
    * k = physics_rate / control_rate physics steps per control period, each a
      semi-implicit (symplectic) Euler step of equation (1): rates first, v ← v + h a(x, v),
      then angles with the new rates, x ← x + h v, h = 1 / physics_rate (Bullet's
      Featherstone integrator);
    * the body–wheel damping d_b plus the motors' electrical damping c_e = k_t k_e / R
      (= stall torque / no-load speed) is Bullet's joint damping, so it acts on the joint
      rates ψ̇_i − θ̇ at every physics step;
    * the wheel–ground damping d_w is held over the period: a joint torque −d_w ψ̇_i per
      wheel plus their sum on the body about the axle, from the wheel rates ψ̇_i at the
      start of the period (ψ̇_l,r = ψ̇ ∓ (b/r) α̇);
    * the motor torque's speed-independent part τ_0 = duty × stall torque is held over
      the period; with torque commands (``drive_is_duty=False``) the duty is the driver's
      (:class:`twin.actuators.dc_motor.MotorDriver`): current limit, back-EMF compensation
      at the shaft speed at the update, supply clip, dead band, PWM rounding. With
      ``motor=None`` the commands are ideal torques (c_e = 0).

``plant="analytic"`` — :class:`twin.plant.analytic_plant.AnalyticPlant`
    classical RK4 of equation (1) at the physics rate with the torque commands held
    (ideal torque sources; d_b and d_w continuous; no motor model).

Not modelled (a clear error): the motors' inductance (the twin then integrates the
current per physics step). Outside the model by construction: pushes, slopes, friction
changes and wheel slip — the twin's contact solver keeps the wheels rolling, which the
rolling-without-slip coordinates [θ, ψ, α] assume.

Everything is elementwise numpy (no matrix products, no BLAS), so results are the same
on every CPU. With the applied duty given (or ideal torques), the held torques do not depend on
the state and the loop runs compiled (``twin.plant._fastpath.windows``, the same operations in
the same order, without fused multiply-adds: bit-identical, tests/test_calibrate_model.py).
SI units throughout: rad, rad/s, N·m, s, Hz.
"""
from __future__ import annotations

import numpy as np

from twin.actuators.dc_motor import DCMotorParams
from twin.errors import TwinError
from twin.params import RobotParams
from twin.plant.analytic import compiled_windows, rhs_batch
from twin.timing import steps_per_control

PLANTS = ("bullet", "analytic")
# the compiled stepping of twin/plant/_fastpath.c, None without it (the Python loop below does the same)
_windows = compiled_windows
_FORCE_PYTHON = False  # tests set it to compare the two paths


def driver_duty(torque_cmd, omega, motor: DCMotorParams) -> np.ndarray:
    """The PWM duty (in [−1, 1]) the driver sets for torque commands at shaft speeds.

    Elementwise :meth:`twin.actuators.dc_motor.MotorDriver.duty`: ``torque_cmd`` in N·m,
    ``omega`` the shaft speed relative to the body (ψ̇_i − θ̇) in rad/s at the update,
    arrays of one shape (or broadcastable). Rounds half to even, as the driver does.
    """
    kt, R, vs = motor.k_t, motor.resistance, motor.supply_voltage
    imax, steps = motor.max_current, float(motor.pwm_steps)
    i_cmd = np.clip(np.asarray(torque_cmd, dtype=float) / kt, -imax, imax)
    v = R * i_cmd
    if motor.back_emf_compensation:
        v = v + kt * np.asarray(omega, dtype=float)
    d = np.clip(v / vs, -1.0, 1.0)
    return np.where(np.abs(d) < motor.dead_band, 0.0, np.round(d * steps) / steps + 0.0)


def stall_part(duty, motor: DCMotorParams) -> np.ndarray:
    """τ_0 = k_t V / R in N·m for a duty (V = duty × supply voltage): duty × stall torque,
    computed as the twin computes it."""
    return motor.k_t * np.asarray(duty, dtype=float) * motor.supply_voltage / motor.resistance


def _checked(S0, drive, params, motor, physics_rate, control_rate, drive_is_duty, plant):
    if not isinstance(params, RobotParams):
        raise TwinError(f"params must be a RobotParams, got {type(params).__name__}")
    if motor is not None and not isinstance(motor, DCMotorParams):
        raise TwinError(f"motor must be DCMotorParams or None (ideal torque sources), got {motor!r}")
    if plant not in PLANTS:
        raise TwinError(f"plant must be one of {', '.join(PLANTS)}, got {plant!r}")
    S0 = np.asarray(S0, dtype=float)
    drive = np.asarray(drive, dtype=float)
    if S0.ndim != 2 or S0.shape[1] != 6:
        raise TwinError(f"S0 must have shape (W, 6) [θ, θ̇, ψ, ψ̇, α, α̇], got {S0.shape}")
    if drive.ndim != 3 or drive.shape[0] != S0.shape[0] or drive.shape[2] != 2:
        raise TwinError(f"drive must have shape (W, N, 2) with W = {S0.shape[0]} (left, right per period), "
                        f"got {drive.shape}")
    if not (np.all(np.isfinite(S0)) and np.all(np.isfinite(drive))):
        raise TwinError("S0 and drive must be finite")
    if drive_is_duty:
        if plant == "analytic" or motor is None:
            raise TwinError("drive_is_duty needs a motor on the PyBullet twin's stepping (plant='bullet', motor "
                            "given): the analytic plant and ideal torque sources take torques in N·m")
        if np.any(np.abs(drive) > 1.0):
            raise TwinError("duties must be in [−1, 1]")
    if plant == "bullet" and motor is not None and motor.inductance > 0.0:
        raise TwinError(f"the motors' inductance ({motor.inductance:g} H) is not modelled: the twin then integrates "
                        f"the current per physics step; calibrate with inductance = 0")
    k = steps_per_control(1.0 / physics_rate, 1.0 / control_rate)
    return S0, drive, k


def step_windows(S0, drive, params: RobotParams, motor: DCMotorParams | None, physics_rate: float = 1000.0,
                 control_rate: float = 200.0, drive_is_duty: bool = False, plant: str = "bullet") -> np.ndarray:
    """The states over N control periods of W windows, stepped as the plant steps them.

    Parameters
    ----------
    S0 : array_like, shape (W, 6)
        Start states [θ (rad), θ̇ (rad/s), ψ (rad), ψ̇ (rad/s), α (rad), α̇ (rad/s)].
    drive : array_like, shape (W, N, 2)
        Per window and period, left and right: the applied PWM duty in [−1, 1]
        (``drive_is_duty=True``), or the wheel torque commands in N·m.
    params : RobotParams
        The plant's physical parameters.
    motor : DCMotorParams or None
        Motors and driver; None: ideal torque sources (the commands are the torques).
        Ignored by ``plant="analytic"``, which has none.
    physics_rate, control_rate : float
        Hz; the control period must be a whole number k of physics steps.
    drive_is_duty : bool
        True: ``drive`` is the duty that was applied (the log's ``duty_l``, ``duty_r``), so
        the driver's rounding and compensation are not recomputed; τ_0 = duty × stall
        torque. False: ``drive`` is torque commands through the driver.
    plant : {"bullet", "analytic"}
        Whose stepping to reproduce (see the module docstring).

    Returns
    -------
    numpy.ndarray, shape (W, N + 1, 6)
        The states at the N + 1 control instants, row 0 being ``S0``.
    """
    S0, drive, k = _checked(S0, drive, params, motor, physics_rate, control_rate, drive_is_duty, plant)
    W, N = drive.shape[0], drive.shape[1]
    h = 1.0 / physics_rate
    out = np.empty((W, N + 1, 6))
    out[:, 0] = S = S0.copy()
    if plant == "analytic":
        for n in range(N):
            ul, ur = drive[:, n, 0], drive[:, n, 1]
            for _ in range(k):
                S = _rk4(S, ul, ur, params, h)
            out[:, n + 1] = S
        return out

    b_r = params.b / params.r
    c_e = 0.0 if motor is None else motor.electrical_damping
    # joint damping d_b + c_e at every physics step; d_w enters as held torques instead
    joint = params.replace(d_b=params.d_b + c_e, d_w=0.0)
    d_w = params.d_w
    if _windows is not None and (motor is None or drive_is_duty) and not _FORCE_PYTHON:
        # the held torques do not depend on the state: the compiled loop (the same arithmetic)
        tau0 = drive if motor is None else stall_part(drive, motor)
        consts = (joint.m11, joint.m12, joint.m22, joint.n_bla, joint.g_b, joint.d_b, d_w, joint.yaw_damping, b_r,
                  joint.m33, h)
        _windows(np.ascontiguousarray(S0), np.ascontiguousarray(tau0, dtype=float), out, consts, k)
        return out
    tau = np.zeros((W, 3))
    for n in range(N):
        theta_d, psi_d, alpha_d = S[:, 1], S[:, 3], S[:, 5]
        rate_l, rate_r = psi_d - b_r * alpha_d, psi_d + b_r * alpha_d  # wheel rates ψ̇_l, ψ̇_r
        if motor is None:
            tau0_l, tau0_r = drive[:, n, 0], drive[:, n, 1]
        else:
            if drive_is_duty:
                duty_l, duty_r = drive[:, n, 0], drive[:, n, 1]
            else:
                duty_l = driver_duty(drive[:, n, 0], rate_l - theta_d, motor)
                duty_r = driver_duty(drive[:, n, 1], rate_r - theta_d, motor)
            tau0_l, tau0_r = stall_part(duty_l, motor), stall_part(duty_r, motor)
        hold_l, hold_r = -d_w * rate_l, -d_w * rate_r
        # the held d_w torques act on the wheel joints, and their sum on the body about the axle
        # (cancelling the joints' reaction on it): net, only the wheels' absolute rates are resisted
        tau[:, 1] = hold_l + hold_r
        ul, ur = tau0_l + hold_l, tau0_r + hold_r
        for _ in range(k):
            a = rhs_batch(S, ul, ur, joint, tau)
            S = S.copy()
            S[:, 1] += h * a[:, 1]
            S[:, 3] += h * a[:, 3]
            S[:, 5] += h * a[:, 5]
            S[:, 0] += h * S[:, 1]
            S[:, 2] += h * S[:, 3]
            S[:, 4] += h * S[:, 5]
        out[:, n + 1] = S
    return out


def _rk4(S, ul, ur, params, dt):
    """One classical RK4 step of equation (1) (:func:`twin.plant.analytic.rk4_step`, batched)."""
    k1 = rhs_batch(S, ul, ur, params)
    k2 = rhs_batch(S + 0.5 * dt * k1, ul, ur, params)
    k3 = rhs_batch(S + 0.5 * dt * k2, ul, ur, params)
    k4 = rhs_batch(S + dt * k3, ul, ur, params)
    return S + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


__all__ = ["PLANTS", "driver_duty", "stall_part", "step_windows"]
