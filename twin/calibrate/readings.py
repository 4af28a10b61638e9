"""What the sensors read along stepped states: the measurement model of the fit.

From the states at the control instants t_0 … t_N of a window (:func:`twin.calibrate.model.
step_windows`), as the twin's sensors form their readings (:mod:`twin.sensors.imu`):

* gyro, the mean angular velocity over each period in body axes: for the body turned by the
  heading α about the vertical and pitched θ about the axle, ω_body = (−α̇ sin θ, θ̇, α̇ cos θ);
  over the period, θ̇ → Δθ / T and α̇ → Δα / T with θ at the period's middle;
* accelerometer, the mean specific force over the period at the IMU's point P (``position`` from
  the axle: x forward, z up), resolved in body axes at the period's end: P's velocity in the
  heading frame is (r ψ̇ + θ̇ d_z, −θ̇ d_x) forward and up, with (d_x, d_z) = P's offset from the
  axle in that frame; the frame turns at α̇, adding −α̇² d_x forward; gravity g up;
* encoders, the wheel angle relative to the body, ψ ∓ (b / r) α − θ (left, right) plus an
  offset per window (the count's zero and the quantiser's phase).

Then the sensor constants: reading = (1 + scale) × true + bias, per axis. SI units: rad, rad/s,
m/s², s.
"""
from __future__ import annotations

import numpy as np


def imu_readings(X, T: float, position, r: float, g: float, gyro_bias, gyro_scale, accel_bias, accel_scale):
    """(W, N, 5) [gyro x, y, z (rad/s), accel x, z (m/s²)] of the N periods of states X (W, N + 1, 6).

    ``T`` s the control period; ``position`` (3,) m the IMU's point from the axle; ``r`` m the
    wheel radius; ``g`` m/s²; ``gyro_bias`` (3,) rad/s; ``gyro_scale`` (3,) 1; ``accel_bias``
    (2,) m/s² and ``accel_scale`` (2,) 1 of the x and z axes.
    """
    th, th_d, ps_d, al = X[..., 0], X[..., 1], X[..., 3], X[..., 4]
    d_th = (th[:, 1:] - th[:, :-1]) / T
    d_al = (al[:, 1:] - al[:, :-1]) / T
    mid = 0.5 * (th[:, 1:] + th[:, :-1])
    sm, cm = np.sin(mid), np.cos(mid)
    gx = (1.0 + gyro_scale[0]) * (-d_al * sm) + gyro_bias[0]
    gy = (1.0 + gyro_scale[1]) * d_th + gyro_bias[1]
    gz = (1.0 + gyro_scale[2]) * (d_al * cm) + gyro_bias[2]
    xp, zp = float(position[0]), float(position[2])
    sn, cs = np.sin(th), np.cos(th)
    dx, dz = xp * cs + zp * sn, -xp * sn + zp * cs  # P from the axle in the heading frame (forward, up)
    u = r * ps_d + th_d * dz
    w = -th_d * dx
    fx = (u[:, 1:] - u[:, :-1]) / T - d_al * d_al * dx[:, 1:]
    fz = (w[:, 1:] - w[:, :-1]) / T + g
    s1, c1 = sn[:, 1:], cs[:, 1:]
    ax = (1.0 + accel_scale[0]) * (fx * c1 - fz * s1) + accel_bias[0]
    az = (1.0 + accel_scale[1]) * (fx * s1 + fz * c1) + accel_bias[1]
    return np.stack([gx, gy, gz, ax, az], axis=-1)


def encoder_angles(X, b_r: float, offsets):
    """(W, N + 1, 2) rad: the wheels' angles relative to the body, left and right, plus
    ``offsets`` (W, 2) rad; ``b_r`` = b / r."""
    th, ps, al = X[..., 0], X[..., 2], X[..., 4]
    return np.stack([ps - b_r * al - th + offsets[:, None, 0], ps + b_r * al - th + offsets[:, None, 1]], axis=-1)


__all__ = ["encoder_angles", "imu_readings"]
