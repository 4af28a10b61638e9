"""What an IMU on the body feels: its angular velocity and the specific force at its
mounting point, from the physics engine's state (the ground truth the noise acts on).

Specific force f = a_P − g (g = (0, 0, −9.81) m/s² in the world): the acceleration of
the sensing point P, with its tangential (ω̇ × r) and centripetal (ω × (ω × r)) terms,
minus gravity, expressed in the body frame. A body at rest pitched θ forward reads
f = (−g sin θ, 0, g cos θ).

The accelerometer reports the mean specific force over its sample interval, resolved in
the body axes at the sample instant: the change of P's velocity over the interval divided
by its length (the engine exposes velocities, not accelerations). That is an ideal
anti-aliasing filter of one sample's width; it is also what lets a strapdown estimator
integrate the samples without a sampling error (the acceleration of a balancing robot
changes by metres per second squared within a 5 ms period). The gyro likewise reports
the mean angular velocity over the interval (the attitude change divided by its length),
so that both are what a delta-angle / delta-velocity IMU integrates.
"""
from __future__ import annotations

import math

from twin.rotations import matrix_rows


def _point_velocity(pose, vel, lever):
    """World velocity of the body point at ``lever`` (m, body frame, from the centre of mass)."""
    R = matrix_rows(pose[1])
    rx = R[0][0] * lever[0] + R[0][1] * lever[1] + R[0][2] * lever[2]
    ry = R[1][0] * lever[0] + R[1][1] * lever[1] + R[1][2] * lever[2]
    rz = R[2][0] * lever[0] + R[2][1] * lever[1] + R[2][2] * lever[2]
    (vx, vy, vz), (wx, wy, wz) = vel
    return (vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx), R


def imu_kinematics(pose, vel, pose_prev, vel_prev, dt: float, lever, g: float):
    """True (gyro, specific force) in the body frame, means over the sample interval ending now.

    Parameters
    ----------
    pose, vel : PyBullet base pose ((x, y, z) m, quaternion) and velocity ((3,) m/s, (3,) rad/s)
        of the body now; ``pose_prev``, ``vel_prev`` at the start of the interval, ``dt`` s
        earlier (the same as now for a body at rest before the first sample).
    lever : (3,) m
        The sensing point in the body frame, relative to the body's centre of mass.
    g : float
        Gravitational acceleration in m/s².

    Returns
    -------
    gyro : (3,) rad/s, the mean angular velocity over the interval (the rotation from the
        previous attitude to this one, divided by ``dt``) in body axes
    accel : (3,) m/s², the mean specific force over the interval in body axes now
    """
    v1, R = _point_velocity(pose, vel, lever)
    return _readings(pose, pose_prev, v1, R, _point_velocity(pose_prev, vel_prev, lever)[0], dt, g)


def _readings(pose, pose_prev, v1, R, v0, dt: float, g: float):
    """:func:`imu_kinematics` from the sensing point's world velocity now (``v1``, with the
    body's rotation matrix ``R``) and at the interval's start (``v0``)."""
    fx, fy, fz = (v1[0] - v0[0]) / dt, (v1[1] - v0[1]) / dt, (v1[2] - v0[2]) / dt + g
    accel = (R[0][0] * fx + R[1][0] * fy + R[2][0] * fz, R[0][1] * fx + R[1][1] * fy + R[2][1] * fz,
             R[0][2] * fx + R[1][2] * fy + R[2][2] * fz)
    # relative rotation q_prev⁻¹ ⊗ q as a rotation vector in the body axes
    ax, ay, az, aw = pose_prev[1]
    bx, by, bz, bw = pose[1]
    ax, ay, az = -ax, -ay, -az
    rw = aw * bw - ax * bx - ay * by - az * bz
    rx = aw * bx + ax * bw + ay * bz - az * by
    ry = aw * by - ax * bz + ay * bw + az * bx
    rz = aw * bz + ax * by - ay * bx + az * bw
    if rw < 0.0:
        rw, rx, ry, rz = -rw, -rx, -ry, -rz
    n = math.sqrt(rx * rx + ry * ry + rz * rz)
    k = (2.0 * math.atan2(n, rw) / n if n > 1e-12 else 2.0) / dt
    return (k * rx, k * ry, k * rz), accel


class ImuMotion:
    """What the IMU mounted on a plant's body feels, sample after sample: the lever arm from
    the body's centre of mass to the sensing point, the sample interval and gravity, and the
    body's kinematics at the previous sample (:func:`imu_kinematics` needs both ends of the
    interval).

    Parameters
    ----------
    plant : Plant
        Read once here: ``com_local`` (the centre of mass in body axes from the axle
        midpoint, m), ``kinematics`` (the body at rest before t = 0) and ``gravity`` (m/s²);
        see :class:`twin.protocols.Plant`.
    imu_position : (3,) m
        The sensing point in body axes from the axle midpoint (``ImuSpec.position``).
    dt : float
        The IMU's sample interval, s.

    ``reading`` is the true (gyro, specific force) of the latest sample, the rest state's
    after construction; :meth:`update` takes the body's kinematics at the next sample.
    """

    __slots__ = ("lever", "dt", "g", "last", "reading", "_v_last")

    def __init__(self, plant, imu_position, dt: float):
        com = plant.com_local
        self.lever = (imu_position[0] - com[0], imu_position[1] - com[1], imu_position[2] - com[2])
        self.dt = dt
        pose, vel = self.last = plant.kinematics  # the body at rest before t = 0
        self.g = plant.gravity
        self.reading = imu_kinematics(pose, vel, pose, vel, dt, self.lever, self.g)
        self._v_last = _point_velocity(pose, vel, self.lever)[0]

    def update(self, kinematics) -> tuple:
        """The true (gyro, accel) of the sample whose interval ends at ``kinematics`` (the
        plant's, PyBullet's layout); it becomes the start of the next interval (its point
        velocity kept: the same numbers :func:`imu_kinematics` would compute again)."""
        pose, vel = kinematics
        v1, R = _point_velocity(pose, vel, self.lever)
        self.reading = reading = _readings(pose, self.last[0], v1, R, self._v_last, self.dt, self.g)
        self.last, self._v_last = kinematics, v1
        return reading
