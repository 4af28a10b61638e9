"""The paper's three experiments on the analytic model, the reference against which the
PyBullet twin is checked, for Python callers: a thin compatibility wrapper over
:class:`twin.sim.loop.ClosedLoop` (through :func:`twin.sim.bullet_loop.simulate_twin`) with the
analytic plant (:class:`twin.plant.analytic_plant.AnalyticPlant`: equation (1), RK4 at
``physics_dt``, ideal torque sources) and ideal sensing (the ``ideal`` estimator: the
controllers see the true state).

On the command line this is ``twin run paper-expN --set plant.model=analytic --set
plant.scale={} --set sensors.sensing=ideal`` (the scenarios' rates, 1 kHz physics and
200 Hz control, are :func:`simulate`'s defaults): the same runs, bit for bit, with outputs,
metrics and a figure; ``twin analytic`` gave way to it (issue 27). The controller's
contract and the limits are checked by the loop.
"""
from __future__ import annotations

import math

import numpy as np

from twin.controllers.cascade import build_cascade
from twin.controllers.lmi import BalanceDesign, design_balance_gains
from twin.errors import TwinError
from twin.experiments import PAPER_EXPERIMENTS, Experiment
from twin.limits import PluginLimits
from twin.params import NOMINAL, RobotParams
from twin.plant.analytic import STATE_NAMES
from twin.plant.analytic_plant import AnalyticPlant
from twin.plant.base import TwinConfig
from twin.sim.bullet_loop import simulate_twin
from twin.sim.runs import Run
from twin.timing import steps_per_control


def simulate(controller, experiment: Experiment, params: RobotParams = NOMINAL,
             duration: float | None = None, physics_dt: float = 0.001, control_dt: float = 0.005,
             x0=None, disturbance=None, controller_name: str = "", limits: PluginLimits | None = None) -> Run:
    """Run ``controller`` (a :class:`twin.protocols.Controller`) on the analytic plant ``params``
    (the "true plant"), reading the true state; returns a :class:`twin.sim.runs.Run` like the twin's
    (``plant`` "analytic", ``sensing`` "ideal"). The same run as ``twin run`` with
    ``plant.model = "analytic"`` and ``sensors.sensing = "ideal"`` (for a paper experiment on the
    nominal plant: ``twin run paper-expN --set plant.model=analytic --set plant.scale={} --set
    sensors.sensing=ideal``); kept as a thin compatibility wrapper for Python callers.

    ``disturbance(t) -> (τ1, τ2, τ3)`` in N·m, optional. ``x0`` (8,) overrides the
    experiment's initial state [θ0, 0, …]. Logged at the control rate: the truth columns
    from the state (ψ_l, ψ_r by rolling without slip, roll 0), the estimates equal to the
    truth, the commands as delivered (ideal torque sources: duties 0, never saturated).
    ``limits``: the controller's wall-time and memory limits, as on the twin
    (:class:`twin.limits.PluginLimits`); None: none.
    """
    steps_per_control(physics_dt, control_dt)  # a whole number of physics steps: said first
    duration = experiment.duration if duration is None else float(duration)
    if not (math.isfinite(duration) and duration >= control_dt):
        raise TwinError(f"duration must be at least one control period ({control_dt:g} s), got {duration:g} s")
    if x0 is not None:
        x = np.asarray(x0, dtype=float)
        if x.shape != (8,) or not np.all(np.isfinite(x)):
            raise TwinError(f"x0 must be 8 finite numbers {STATE_NAMES}, got shape {x.shape}")
    if limits is not None and not isinstance(limits, PluginLimits):
        raise TwinError(f"limits must be a twin.limits.PluginLimits or None, got {limits!r}")
    config = TwinConfig(params=params, physics_rate=1.0 / physics_dt, control_rate=1.0 / control_dt, motor=None)
    plant = AnalyticPlant(config, experiment.theta0, disturbance=disturbance, initial=x0)
    return simulate_twin(controller, experiment, config, duration=duration, controller_name=controller_name,
                         sensors=None, estimator="ideal", model_params=params, plant=plant, limits=limits)


def run_paper_experiment(number: int, kind: str = "it2", design: BalanceDesign | None = None,
                         plant: RobotParams = NOMINAL, model: RobotParams = NOMINAL, **kwargs) -> Run:
    """Paper experiment 1, 2 or 3 with the ``kind`` controllers designed on ``model``."""
    if number not in PAPER_EXPERIMENTS:
        raise TwinError(f"paper experiment must be 1, 2 or 3, got {number!r}")
    exp = PAPER_EXPERIMENTS[number]
    design = design or design_balance_gains(model)
    ctrl = build_cascade(kind, design, exp.targets, model)
    return simulate(ctrl, exp, plant, controller_name=kind, **kwargs)
