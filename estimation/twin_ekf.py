"""filterpy's ExtendedKalmanFilter as the EKF's reference (pure-Python) path uses it.

Kept apart from :mod:`estimation.ekf` so that the compiled path, which never steps this
class, does not import filterpy: its package ``__init__`` imports all of filterpy, and
``filterpy.stats`` imports scipy.stats (about 0.8 s of a 20 s run's 3.4 s process).
``estimation.ekf.TwinEKF`` still names this class.

The predict and update steps are filterpy's equations (P = F P Fᵀ + Q; the Joseph-form
update with K = P Hᵀ S⁻¹) with the products and the inverse of
:mod:`estimation.detlinalg` in place of filterpy's ``np.dot``/``linalg.inv``: those run in
the BLAS numpy bundles, whose last bits depend on the CPU kernel it picks at load time
(issue 25), and the filter's output feeds the controllers. filterpy still holds the
filter's attributes (x, P, F, Q, R, the priors and posteriors).
"""
from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from estimation.detlinalg import inv, mm
from estimation.ekf import N, cov_predict


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

    def predict(self, u=0):
        """filterpy's predict, P = F P Fᵀ + Q, summed as the compiled kernel does
        (:func:`estimation.ekf.cov_predict`: F is the strapdown step's)."""
        self.predict_x(u)
        self.P = cov_predict(self.F, self.P, self.Q)
        self.x_prior = np.copy(self.x)
        self.P_prior = np.copy(self.P)

    def update(self, z, HJacobian, Hx, R=None, args=(), hx_args=(), residual=np.subtract):
        """filterpy's update (Joseph form) with the gain's rows of the consider states zeroed
        (the Schmidt–Kalman update: the Joseph form is exact for any gain, so P keeps their
        uncertainty and its correlations; only their estimates are never moved).

        Every sum runs in the order of the compiled kernel's ``kalman_update`` (estimation/_ekf.c):
        K = (P Hᵀ) S⁻¹ with S⁻¹ by the explicit formula, x + K y and I − K H a row of H at a
        time, P = ((I − K H) P)(I − K H)ᵀ, then + K R Kᵀ a row of H at a time (R diagonal)."""
        if R is None:
            R = self.R
        elif np.isscalar(R):
            R = np.eye(len(z)) * R
        H = HJacobian(self.x, *args)
        PHT = mm(self.P, H.T)
        self.S = mm(H, PHT) + R
        self.SI = inv(self.S)
        self.K = mm(PHT, self.SI)
        if self.consider.any():
            self.K[self.consider] = 0.0
        self.y = residual(z, Hx(self.x, *hx_args))
        x = self.x.copy()
        I_KH = self._I.copy()
        for a in range(H.shape[0]):
            x += self.K[:, a] * self.y[a]
            I_KH -= np.multiply.outer(self.K[:, a], H[a])
        self.x = x
        P = mm(mm(I_KH, self.P), I_KH.T)
        for a in range(H.shape[0]):
            P += np.multiply.outer(self.K[:, a] * R[a, a], self.K[:, a])
        self.P = P
        self._log_likelihood = self._likelihood = self._mahalanobis = None
        self.z = np.copy(z)
        self.x_post = self.x.copy()
        self.P_post = self.P.copy()
