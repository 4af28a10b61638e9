"""State estimation from the twin's sensors: θ, ψ, α and their rates, with covariance.

``model``       what the estimator knows: equation (1), the motor driver, the sensors' models and noise
``ekf``         the extended Kalman filter (filterpy) with gating and latency handling
``baselines``   a complementary filter and the two-state angle-plus-bias Kalman filter of hobby robots
``consistency`` NEES, NIS and their χ² bounds

:func:`build_estimator` makes any of them for a twin configuration.
"""
from __future__ import annotations

import importlib

ESTIMATORS = ("ekf", "complementary", "kalman2")
# filterpy and scipy load on first use, so that the command line starts quickly
_LAZY = {"AngleBiasKalman": "baselines", "ComplementaryFilter": "baselines", "EKFEstimator": "ekf",
         "Estimate": "ekf", "EstimatorModel": "model"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"estimation.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'estimation' has no attribute {name!r}")


def build_estimator(kind: str, sensors, control_rate: float, motor, params, alpha0: float = 0.0,
                    compiled: bool | None = None):
    """An estimator of ``kind`` (one of :data:`ESTIMATORS`) for these sensors.

    ``sensors`` a :class:`twin.sensors.SensorConfig`; ``control_rate`` Hz; ``motor`` the
    motors' specification (or None); ``params`` the robot model the estimator assumes;
    ``alpha0`` the initial heading (rad); ``compiled`` the EKF's implementation (see
    :class:`estimation.ekf.EKFEstimator`; the baselines have one).
    """
    from estimation.baselines import AngleBiasKalman, ComplementaryFilter
    from estimation.ekf import EKFEstimator
    from estimation.model import EstimatorModel
    from twin.errors import TwinError

    if kind not in ESTIMATORS:
        raise TwinError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {kind!r}")
    if kind == "ekf":
        every, d_imu, d_enc = sensors.steps(control_rate)
        model = EstimatorModel(params, motor, sensors.imu, sensors.encoders, control_rate)
        return EKFEstimator(model, every, d_imu, d_enc, alpha0=alpha0, compiled=compiled)
    cls = ComplementaryFilter if kind == "complementary" else AngleBiasKalman
    return cls(control_rate, params.r, params.b, alpha0)


def replay(estimator, run, measurements=None):
    """The estimates (n, 6) [θ, θ̇, ψ, ψ̇, α, α̇] of a fresh ``estimator`` fed a twin run's
    readings (or ``measurements``) and its commands, exactly as the loop fed them."""
    import numpy as np

    meas = run.measurements if measurements is None else measurements
    cmds = run.commands[:, :2]
    out = [estimator.start(meas[0])]
    out += [estimator.step(m, cmds[i]) for i, m in enumerate(meas[1:])]
    return np.array(out, dtype=float)


__all__ = ["ESTIMATORS", "AngleBiasKalman", "ComplementaryFilter", "EKFEstimator", "Estimate", "EstimatorModel",
           "build_estimator", "replay"]
