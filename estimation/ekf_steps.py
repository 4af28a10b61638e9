"""The EKF's state vector and the two filter steps every implementation runs.

The 12 states (:data:`STATE_NAMES`, their indices ``TH`` … ``SAZ``), :func:`cov_predict`
(P = F P Fᵀ + Q for the strapdown step's F) and :func:`joseph_update` (the Joseph-form update
with the consider states' gain rows zeroed), every sum in the order of the compiled kernel
(estimation/_ekf.c). Both implementations of :mod:`estimation.ekf_core` run them: the
compiled core's Python-side mirror and filterpy's :class:`~estimation.twin_ekf.TwinEKF`. They
live below both, with numpy alone, so that the compiled path never imports filterpy and
``twin_ekf`` never imports the core that builds it.
"""
from __future__ import annotations

import numpy as np

from estimation.detlinalg import inv, mm

STATE_NAMES = ("theta", "psi", "imu_speed", "alpha", "gyro_bias_y", "gyro_bias_z", "encoder_zero", "gyro_scale_y",
               "encoder_heading_zero", "gyro_scale_z", "accel_scale_x", "accel_scale_z")
STATE_UNITS = ("rad", "rad", "m/s", "rad", "rad/s", "rad/s", "rad", "1", "rad", "1", "1", "1")
N = len(STATE_NAMES)
TH, PS, V, AL, BY, BZ, C0, SY, H0, SZ, SAX, SAZ = range(N)

_F_ROWS = [TH, AL, V, PS]  # the rows of the strapdown step's F that are not the identity's


def cov_predict(F, P, Q) -> np.ndarray:
    """F P Fᵀ + Q for the strapdown step's F (:meth:`~estimation.ekf_filter.StrapdownFilter.propagate`: the
    identity but in rows θ, α, v, ψ), as the compiled kernel's ``cov_predict``: only those rows of F P and
    those columns of (F P) Fᵀ are sums, in ascending order (:mod:`estimation.detlinalg`); the
    others are P's own entries, which the full product would give too (x·1 plus zeros)."""
    A = P.copy()
    A[_F_ROWS] = mm(F[_F_ROWS], P)
    out = A.copy()
    out[:, _F_ROWS] = mm(A, F[_F_ROWS].T)
    return out + Q


def joseph_update(x, P, z, y_of, H, R, consider):
    """(x⁺, P⁺, y, S, S⁻¹, K): the Joseph-form update of prior (x, P) with measurement z,
    innovation ``y_of(x)`` (z less the predicted measurement), Jacobian H and noise R (diagonal),
    the gain's rows of the ``consider`` states (a (12,) mask) zeroed (Schmidt–Kalman: the Joseph
    form is exact for any gain, so P keeps their uncertainty and correlations).

    Every sum runs in the order of the compiled kernel's ``kalman_update`` (estimation/_ekf.c):
    K = (P Hᵀ) S⁻¹ with S⁻¹ by the explicit formula, x + K y and I − K H a row of H at a time,
    P = ((I − K H) P)(I − K H)ᵀ, then + K R Kᵀ a row of H at a time."""
    PHT = mm(P, H.T)
    S = mm(H, PHT) + R
    SI = inv(S)
    K = mm(PHT, SI)
    if consider.any():
        K[consider] = 0.0
    y = y_of(x)
    x = x.copy()
    I_KH = np.eye(len(x))
    for a in range(H.shape[0]):
        x += K[:, a] * y[a]
        I_KH -= np.multiply.outer(K[:, a], H[a])
    P = mm(mm(I_KH, P), I_KH.T)
    for a in range(H.shape[0]):
        P += np.multiply.outer(K[:, a] * R[a, a], K[:, a])
    return x, P, y, S, SI, K


__all__ = ["AL", "BY", "BZ", "C0", "H0", "N", "PS", "SAX", "SAZ", "STATE_NAMES", "STATE_UNITS", "SY", "SZ", "TH", "V",
           "cov_predict", "joseph_update"]
