"""filterpy's ExtendedKalmanFilter as the EKF's reference (pure-Python) path uses it.

Kept apart from :mod:`estimation.ekf` so that the compiled path, which never steps this
class, does not import filterpy: its package ``__init__`` imports all of filterpy, and
``filterpy.stats`` imports scipy.stats (about 0.8 s of a 20 s run's 3.4 s process).
``estimation.ekf.TwinEKF`` still names this class.
"""
from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from estimation.ekf import N


class TwinEKF(ExtendedKalmanFilter):
    """filterpy's EKF whose nonlinear prediction is computed (with F and Q) beforehand, and
    whose update leaves the consider states (``consider``, a (12,) mask) uncorrected."""

    def __init__(self, consider=None):
        super().__init__(dim_x=N, dim_z=2)
        self.x = np.zeros(N)
        self._x_next = self.x
        self.consider = np.zeros(N, dtype=bool) if consider is None else np.asarray(consider, dtype=bool)

    def predict_x(self, u=0):
        self.x = self._x_next

    def update(self, z, HJacobian, Hx, R=None, args=(), hx_args=(), residual=np.subtract):
        """filterpy's update (Joseph form) with the gain's rows of the consider states zeroed
        (the Schmidt–Kalman update: the Joseph form is exact for any gain, so P keeps their
        uncertainty and its correlations; only their estimates are never moved)."""
        if not self.consider.any():
            return super().update(z, HJacobian, Hx, R=R, args=args, hx_args=hx_args, residual=residual)
        H = HJacobian(self.x)
        PHT = self.P @ H.T
        self.S = H @ PHT + R
        self.SI = np.linalg.inv(self.S)
        self.K = PHT @ self.SI
        self.K[self.consider] = 0.0
        self.y = residual(z, Hx(self.x))
        self.x = self.x + self.K @ self.y
        I_KH = self._I - self.K @ H
        self.P = I_KH @ self.P @ I_KH.T + self.K @ R @ self.K.T
