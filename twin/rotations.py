"""Rotation helpers in one place: quaternions (x, y, z, w), rotation matrices as rows, 3-vectors.

Plain Python floats on purpose: they run in the twin's per-step hot path (the IMU and the
initial pose), where numpy's per-call overhead would dominate.
"""
from __future__ import annotations

import math


def quat_from_matrix(R) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix given as rows."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R
    tr = m00 + m11 + m22
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        return ((m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s)
    if m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        return (0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s)
    if m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        return ((m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s)
    s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
    return ((m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s)


def matrix_rows(q):
    """The rotation matrix of the unit quaternion ``q`` = (x, y, z, w), as three rows."""
    x, y, z, w = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
            (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
            (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))


def quat_multiply(a, b) -> tuple[float, float, float, float]:
    """Quaternion product a ⊗ b, (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def body_quaternion(theta: float, alpha: float, roll: float = 0.0) -> tuple[float, float, float, float]:
    """(x, y, z, w) of R = Rz(α) Rx(φ) Ry(θ): heading ``alpha``, ``roll``, pitch ``theta`` (rad)."""
    qz = (0.0, 0.0, math.sin(0.5 * alpha), math.cos(0.5 * alpha))
    qx = (math.sin(0.5 * roll), 0.0, 0.0, math.cos(0.5 * roll))
    qy = (0.0, math.sin(0.5 * theta), 0.0, math.cos(0.5 * theta))
    return quat_multiply(quat_multiply(qz, qx), qy)


def unit(v):
    """``v`` / ‖v‖."""
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (v[0] / n, v[1] / n, v[2] / n)


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


__all__ = ["body_quaternion", "cross", "dot", "matrix_rows", "quat_from_matrix", "quat_multiply", "unit"]


def mounting_matrix(roll: float, pitch: float, yaw: float):
    """C (3 rows) with v_body = C v_imu for an IMU whose axes are the body's turned by ``yaw``
    about z, then ``pitch`` about the new y, then ``roll`` about the newest x (rad): Rz Ry Rx."""
    (cr, sr), (cp, sp), (cy, sy) = ((math.cos(v), math.sin(v)) for v in (roll, pitch, yaw))
    return ((cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
            (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
            (-sp, cp * sr, cp * cr))
