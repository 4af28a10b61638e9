"""Closed loop on the analytic model: the paper's three experiments, the reference
against which the PyBullet twin is checked.

The plant (equation 1, :mod:`twin.plant.analytic`) is integrated with fixed-step RK4 at
``physics_dt``; the controllers run every ``control_dt`` (a whole number of physics
steps) with a zero-order hold, as on the real robot's microcontroller. The controllers
see the true state here (the estimator comes with the sensor models).
"""
from __future__ import annotations

import math
from time import perf_counter

import numpy as np

from twin.controllers.cascade import build_cascade
from twin.controllers.lmi import BalanceDesign, design_balance_gains
from twin.errors import PluginError, TwinError
from twin.experiments import PAPER_EXPERIMENTS, Experiment
from twin.limits import MEMORY_EVERY, PluginLimits, RunGuard
from twin.params import NOMINAL, RobotParams
from twin.plant.analytic import STATE_NAMES, rk4_step, wheel_angles
from twin.protocols import describe_object, one_line
from twin.runs import COMMAND_UNITS, Run
from twin.timing import steps_per_control


def simulate(controller, experiment: Experiment, params: RobotParams = NOMINAL,
             duration: float | None = None, physics_dt: float = 0.001, control_dt: float = 0.005,
             x0=None, disturbance=None, controller_name: str = "", limits: PluginLimits | None = None) -> Run:
    """Run ``controller`` (a :class:`twin.protocols.Controller`) on the analytic plant ``params``
    (the "true plant"), reading the true state; returns a :class:`twin.runs.Run` like the twin's.

    ``disturbance(t) -> (τ1, τ2, τ3)`` in N·m, optional. ``x0`` (8,) overrides the
    experiment's initial state [θ0, 0, …]. Logged at the control rate: the truth columns
    from the state (ψ_l, ψ_r by rolling without slip, roll 0), the estimates equal to the
    truth, the commands as delivered (ideal torque sources: duties 0, never saturated).
    ``limits``: the controller's wall-time limits per call and per run, as on the twin
    (:class:`twin.limits.PluginLimits`; its memory limit too); None: none.
    """
    k = steps_per_control(physics_dt, control_dt)
    duration = experiment.duration if duration is None else float(duration)
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    n_ctrl = int(round(duration / control_dt))  # logged at the control rate: duration rounds to it
    x = np.zeros(8)
    x[0] = experiment.theta0
    if x0 is not None:
        x = np.asarray(x0, dtype=float)
        if x.shape != (8,) or not np.all(np.isfinite(x)):
            raise TwinError(f"x0 must be 8 finite numbers {STATE_NAMES}, got shape {x.shape}")
        x = x.copy()
    targets = experiment.targets
    if limits is not None and not isinstance(limits, PluginLimits):
        raise TwinError(f"limits must be a twin.limits.PluginLimits or None, got {limits!r}")
    guard = RunGuard(limits, controller, None, control_dt) if limits is not None and limits.active else None
    if guard is not None:
        guard.start()  # the run's clock: reset() counts towards limits.run_wall_s, as on the twin
    if hasattr(controller, "reset"):
        t0 = perf_counter()
        try:
            controller.reset(targets)
        except Exception as exc:  # noqa: BLE001 -- the controller's failure, in one line
            raise PluginError(f"controller {describe_object(controller)}: reset() raised {type(exc).__name__}: "
                              f"{one_line(exc)}") from None
        if guard is not None:
            t1 = perf_counter()
            guard.charge("controller", t1 - t0, t1, 0, per_step=False)
    log = np.empty((n_ctrl + 1, 8))
    names = ("ul_cmd", "ur_cmd") + tuple(getattr(controller, "signals", ()))
    cmds = np.zeros((n_ctrl + 1, len(names)))
    for i in range(n_ctrl + 1):
        log[i] = x
        if not np.all(np.isfinite(x)):
            raise TwinError(f"the analytic simulation diverged at t = {i * control_dt:.3f} s")
        t0 = perf_counter()
        try:
            c = tuple(float(v) for v in controller(x[:6], targets))  # (ul, ur, *signals)
        except Exception as exc:  # noqa: BLE001 -- the controller's failure, in one line
            raise PluginError(f"controller {describe_object(controller)}: __call__() failed at t = {i * control_dt:.3f} "
                              f"s: {type(exc).__name__}: {one_line(exc)}") from None
        if guard is not None:
            t1 = perf_counter()
            guard.charge("controller", t1 - t0, t1, i)
            if guard.memory_bytes is not None and i % MEMORY_EVERY == 0:
                guard.memory(i)
        if len(c) != len(names) or not all(map(math.isfinite, c)):
            raise PluginError(f"controller {describe_object(controller)} returned {c!r} at t = {i * control_dt:.3f} s; "
                              f"expected {len(names)} finite numbers ({', '.join(names)}; torques in N·m)")
        cmds[i] = c
        if i == n_ctrl:
            break
        for j in range(k):
            tau = None if disturbance is None else disturbance((i * k + j) * physics_dt)
            x = rk4_step(x, c[0], c[1], params, physics_dt, tau)
    return _as_run(log, cmds, names, control_dt, params, experiment, controller_name, controller)


def _as_run(log: np.ndarray, cmds: np.ndarray, names: tuple, control_dt: float, params: RobotParams,
            experiment: Experiment, controller_name: str, controller) -> Run:
    """The analytic trajectory as a :class:`~twin.runs.Run` (columns of the twin's)."""
    n = len(log)
    t = np.arange(n) * control_dt
    col = {name: log[:, i] for i, name in enumerate(STATE_NAMES)}
    psi_l, psi_r = wheel_angles(log.T, params)
    turn = params.b / params.r * col["alpha_dot"]
    zeros = np.zeros(n)
    truth = np.column_stack([t, col["theta"], col["theta_dot"], psi_l, psi_r, col["psi"], col["psi_dot"], col["alpha"],
                             col["alpha_dot"], params.r * col["psi"], col["x"], col["y"], zeros,
                             col["psi_dot"] - turn, col["psi_dot"] + turn])
    delivered = np.vstack([cmds[:-1, :2], np.zeros((1, 2))])  # the last command is never applied
    actuation = np.column_stack([zeros, zeros, delivered, zeros, zeros])
    units = {**COMMAND_UNITS, **getattr(controller, "signal_units", {})}
    return Run(t, truth, cmds, actuation, np.zeros((n, 3)), "ok", "", None, experiment, controller_name,
               estimates=truth[:, [1, 2, 5, 6, 7, 8]].copy(), sensing="ideal", model_params=params,
               command_names=names, command_units=tuple(units.get(k, "1") for k in names), plant="analytic")


def run_paper_experiment(number: int, kind: str = "it2", design: BalanceDesign | None = None,
                         plant: RobotParams = NOMINAL, model: RobotParams = NOMINAL, **kwargs) -> Run:
    """Paper experiment 1, 2 or 3 with the ``kind`` controllers designed on ``model``."""
    if number not in PAPER_EXPERIMENTS:
        raise TwinError(f"paper experiment must be 1, 2 or 3, got {number!r}")
    exp = PAPER_EXPERIMENTS[number]
    design = design or design_balance_gains(model)
    ctrl = build_cascade(kind, design, exp.targets, model)
    return simulate(ctrl, exp, plant, controller_name=kind, **kwargs)
