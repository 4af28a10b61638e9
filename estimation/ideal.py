"""Ideal sensing as an estimator: the ground truth passed through.

A reference, not an estimator: it reads ``measurement.truth``, which the loop attaches
only for estimators that declare ``reads_truth = True``. With it the controllers act on
the true [θ, θ̇, ψ, ψ̇, α, α̇], which separates what the controllers do from what the
sensors and the estimator cost them.
"""
from __future__ import annotations

from twin.errors import TwinError
from twin.protocols import Estimate


class IdealEstimator:
    """Returns the true state [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s) at every control instant."""

    name = "ideal"
    reads_truth = True

    def start(self, measurement) -> Estimate:
        return self.step(measurement, None)

    def step(self, measurement, command) -> Estimate:
        truth = measurement.truth
        if truth is None:
            raise TwinError("the ideal estimator needs the ground truth in the measurement (measurement.truth)")
        return Estimate(truth.theta, truth.theta_dot, truth.psi, truth.psi_dot, truth.alpha, truth.alpha_dot)

    def stats(self) -> dict:
        return {}
