"""mtwip-twin: a digital twin of a mobile two-wheeled inverted pendulum under IT2 fuzzy control.

Data flow: plant (``twin.plant``) -> sensors (``twin.sensors``) -> estimator (``estimation``)
-> controllers (``twin.controllers``, built on ``twin.fuzzy``) -> actuators -> plant, one
control period per :meth:`ClosedLoop.step`; the contracts between them are in
``twin.protocols`` and the kinds (built-in names or import paths) in ``twin.registry``.

The Python API, loaded on first use::

    from twin import load_scenario, run_scenario
    result = run_scenario(load_scenario("paper-exp3"), ["it2", "lqr"])
    result.metrics["lqr"]["settling_time_s"]

One run, as a typed specification (:class:`twin.sim.spec.RunSpec`)::

    from twin import load_scenario, simulate
    run = simulate(load_scenario("paper-exp1").run_spec("it2"))
"""
from __future__ import annotations

import importlib

from twin.errors import InfeasibleDesign, PluginError, TwinError
from twin.params import NOMINAL, RobotParams

__version__ = "0.1.0"

_LAZY = {
    "ClosedLoop": "twin.sim.loop", "Run": "twin.sim.runs", "Targets": "twin.protocols", "Controller": "twin.protocols",
    "Estimator": "twin.protocols", "Experiment": "twin.experiments", "PAPER_EXPERIMENTS": "twin.experiments",
    "simulate_twin": "twin.sim.bullet_loop", "load_scenario": "twin.scenarios", "run_scenario": "twin.workflows.run",
    "build_controller": "twin.registry", "build_estimator": "twin.registry", "BuildContext": "twin.registry",
    "TwinConfig": "twin.plant.base", "SensorConfig": "twin.sensors",
    "RunSpec": "twin.sim.spec", "simulate": "twin.sim.simulate", "build_loop": "twin.sim.simulate",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'twin' has no attribute {name!r}")


__all__ = ["NOMINAL", "RobotParams", "TwinError", "InfeasibleDesign", "PluginError", "__version__", *_LAZY]
