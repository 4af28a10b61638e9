"""What an IMU on the body feels: its angular velocity and the specific force at its
mounting point, from the physics engine's state (the ground truth the noise acts on).

Specific force f = a_P − g (g = (0, 0, −9.81) m/s² in the world): the acceleration of
the sensing point P, with its tangential (ω̇ × r) and centripetal (ω × (ω × r)) terms,
minus gravity, expressed in the body frame. A body at rest pitched θ forward reads
f = (−g sin θ, 0, g cos θ).

The acceleration is the change of P's velocity over the last physics step (1 ms at the
default rate) divided by the step: the engine exposes velocities, not accelerations,
and one step is the finest time it resolves.
"""
from __future__ import annotations


def _rows(q):
    x, y, z, w = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
            (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
            (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))


def _point_velocity(pose, vel, lever):
    """World velocity of the body point at ``lever`` (m, body frame, from the centre of mass)."""
    R = _rows(pose[1])
    rx = R[0][0] * lever[0] + R[0][1] * lever[1] + R[0][2] * lever[2]
    ry = R[1][0] * lever[0] + R[1][1] * lever[1] + R[1][2] * lever[2]
    rz = R[2][0] * lever[0] + R[2][1] * lever[1] + R[2][2] * lever[2]
    (vx, vy, vz), (wx, wy, wz) = vel
    return (vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx), R


def imu_kinematics(pose, vel, pose_prev, vel_prev, dt: float, lever, g: float):
    """True (gyro, specific force) in the body frame at the end of a physics step.

    Parameters
    ----------
    pose, vel : PyBullet base pose ((x, y, z) m, quaternion) and velocity ((3,) m/s, (3,) rad/s)
        of the body now; ``pose_prev``, ``vel_prev`` one physics step of ``dt`` s earlier.
    lever : (3,) m
        The sensing point in the body frame, relative to the body's centre of mass.
    g : float
        Gravitational acceleration in m/s².

    Returns
    -------
    gyro : (3,) rad/s, angular velocity in body axes
    accel : (3,) m/s², specific force in body axes
    """
    v1, R = _point_velocity(pose, vel, lever)
    v0, _ = _point_velocity(pose_prev, vel_prev, lever)
    fx, fy, fz = (v1[0] - v0[0]) / dt, (v1[1] - v0[1]) / dt, (v1[2] - v0[2]) / dt + g
    wx, wy, wz = vel[1]
    # body components: Rᵀ v
    gyro = (R[0][0] * wx + R[1][0] * wy + R[2][0] * wz, R[0][1] * wx + R[1][1] * wy + R[2][1] * wz,
            R[0][2] * wx + R[1][2] * wy + R[2][2] * wz)
    accel = (R[0][0] * fx + R[1][0] * fy + R[2][0] * fz, R[0][1] * fx + R[1][1] * fy + R[2][1] * fz,
             R[0][2] * fx + R[1][2] * fy + R[2][2] * fz)
    return gyro, accel
