"""State estimation from the twin's sensors: θ, ψ, α and their rates, with covariance.

``model``       what the estimator knows: equation (1), the motor driver, the sensors' models and noise
``ekf``         the extended Kalman filter: its policies composed on a filter core
``ekf_core``    the filter core: one interface, a filterpy (reference) and a compiled implementation
``baselines``   a complementary filter and the two-state angle-plus-bias Kalman filter of hobby robots
``ideal``       the ground truth passed through (ideal sensing, a reference)
``consistency`` NEES, NIS and their χ² bounds

Each meets :class:`twin.protocols.Estimator`. The package depends on the contracts
(:mod:`twin.protocols`), the sensor data types and the robot model, never on the twin's
registry: the kinds and their names are in :mod:`twin.registry`, and
:func:`twin.registry.build_estimator_for` makes any of them for a twin configuration.
"""
from __future__ import annotations

import importlib

# filterpy and scipy load on first use, so that the command line starts quickly
_LAZY = {"AngleBiasKalman": "baselines", "ComplementaryFilter": "baselines", "EKFEstimator": "ekf",
         "Estimate": "ekf", "EstimatorModel": "model", "IdealEstimator": "ideal"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"estimation.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'estimation' has no attribute {name!r}")


def replay(estimator, run, measurements=None):
    """The estimates (n, 6) [θ, θ̇, ψ, ψ̇, α, α̇] of a fresh ``estimator`` fed a twin run's
    readings (or ``measurements``) and its commands, exactly as the loop fed them."""
    import numpy as np

    meas = run.measurements if measurements is None else measurements
    cmds = run.commands[:, :2]
    out = [estimator.start(meas[0])]
    out += [estimator.step(m, cmds[i]) for i, m in enumerate(meas[1:])]
    return np.array(out, dtype=float)


__all__ = ["AngleBiasKalman", "ComplementaryFilter", "EKFEstimator", "Estimate", "EstimatorModel", "replay"]
