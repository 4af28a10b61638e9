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

from estimation.ekf_steps import N, cov_predict, joseph_update


class TwinEKF(ExtendedKalmanFilter):
    """filterpy's EKF whose nonlinear prediction is computed (with F and Q) beforehand and
    handed to :meth:`predict`, and whose update leaves the consider states (``consider``, a
    (12,) mask) uncorrected. :class:`estimation.ekf_core.PythonCore` steps it."""

    def __init__(self, consider=None):
        super().__init__(dim_x=N, dim_z=2)
        self.x = np.zeros(N)
        self.consider = np.zeros(N, dtype=bool) if consider is None else np.asarray(consider, dtype=bool)

    def predict_x(self, u=0):
        """The state is predicted beforehand (``predict(x_next=...)``): nothing to do here."""

    def predict(self, u=0, x_next=None, F=None, Q=None):
        """filterpy's predict with the predicted state ``x_next`` (and the step's F, Q), P = F P Fᵀ + Q
        summed as the compiled kernel does (:func:`estimation.ekf_steps.cov_predict`: F is the
        strapdown step's)."""
        if F is not None:
            self.F = F
        if Q is not None:
            self.Q = Q
        if x_next is not None:
            self.x = x_next
        else:
            self.predict_x(u)
        self.P = cov_predict(self.F, self.P, self.Q)
        self.x_prior = np.copy(self.x)
        self.P_prior = np.copy(self.P)

    def update(self, z, HJacobian, Hx, R=None, args=(), hx_args=(), residual=np.subtract):
        """filterpy's update (Joseph form) with the gain's rows of the consider states zeroed
        (the Schmidt–Kalman update: the Joseph form is exact for any gain, so P keeps their
        uncertainty and its correlations; only their estimates are never moved), every sum in
        the compiled kernel's order (:func:`estimation.ekf_steps.joseph_update`)."""
        if R is None:
            R = self.R
        elif np.isscalar(R):
            R = np.eye(len(z)) * R
        H = HJacobian(self.x, *args)
        self.x, self.P, self.y, self.S, self.SI, self.K = joseph_update(
            self.x, self.P, z, lambda x: residual(z, Hx(x, *hx_args)), H, R, self.consider)
        self._log_likelihood = self._likelihood = self._mahalanobis = None
        self.z = np.copy(z)
        self.x_post = self.x.copy()
        self.P_post = self.P.copy()
