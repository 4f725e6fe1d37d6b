"""Orientation conversions, as the reference's formulas give them, and the quaternion.

M maps earth-frame vectors into the sensor frame (V_sensor = M . V_earth); the earth
frame's axes are north, east, down. Euler angles are the "aircraft" ZYX set: pitch =
asin(-M13), roll = atan2(M23, M33), yaw = atan2(M12, M11). Pitch is singular at +/-90
degrees; the matrix is not.

The quaternion is the sensor's orientation in the earth frame: the rotation of M's
transpose, which takes a vector's sensor coordinates to its earth coordinates (what
Foxglove's FrameTransform and ROS call a child frame's rotation in its parent). It is
the same rotation as roll, pitch and yaw: Rz(yaw) . Ry(pitch) . Rx(roll) = M^T.
"""

from __future__ import annotations

import math

from .fields import Matrix

Quaternion = tuple[float, float, float, float]
"""(w, x, y, z), of unit length, w >= 0 (q and -q are one rotation: this one is chosen)."""
NAN_QUATERNION: Quaternion = (math.nan, math.nan, math.nan, math.nan)
"""What a matrix with a NaN gives: never an exception."""


def euler_from_matrix(m: Matrix) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians from the orientation matrix M (NaN from NaN)."""
    sin_pitch = -m[0][2]
    pitch = (math.asin(max(-1.0, min(1.0, sin_pitch))) if sin_pitch == sin_pitch
             else math.nan)
    roll = math.atan2(m[1][2], m[2][2])
    yaw = math.atan2(m[0][1], m[0][0])
    return roll, pitch, yaw


def matrix_from_euler(roll: float, pitch: float, yaw: float) -> Matrix:
    """The orientation matrix M for Euler angles in radians (the reference's formula)."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    return (
        (cy * cp, sy * cp, -sp),
        (cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr),
        (cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr),
    )


def quaternion_from_matrix(m: Matrix) -> Quaternion:
    """The sensor's orientation in the earth frame from M, as (w, x, y, z).

    Written for R = M^T (R[i][j] = M[j][i]), from the largest of R's trace and diagonal
    (the square root that loses no precision); normalised, since a float32 matrix from
    the node is only nearly orthonormal."""
    (m11, m12, m13), (m21, m22, m23), (m31, m32, m33) = m
    # R = M^T: R11 = m11, R12 = m21, R13 = m31, R21 = m12, ... so R32 - R23 = m23 - m32
    trace = m11 + m22 + m33
    if trace >= m11 and trace >= m22 and trace >= m33:
        s = 2.0 * math.sqrt(max(0.0, 1.0 + trace))
        q = (0.25 * s, (m23 - m32) / s if s else 0.0, (m31 - m13) / s if s else 0.0,
             (m12 - m21) / s if s else 0.0)
    elif m11 >= m22 and m11 >= m33:
        s = 2.0 * math.sqrt(max(0.0, 1.0 + m11 - m22 - m33))
        q = ((m23 - m32) / s if s else 0.0, 0.25 * s, (m21 + m12) / s if s else 0.0,
             (m31 + m13) / s if s else 0.0)
    elif m22 >= m33:
        s = 2.0 * math.sqrt(max(0.0, 1.0 + m22 - m11 - m33))
        q = ((m31 - m13) / s if s else 0.0, (m21 + m12) / s if s else 0.0, 0.25 * s,
             (m32 + m23) / s if s else 0.0)
    else:  # (also every comparison with a NaN: it comes out NaN)
        s = 2.0 * math.sqrt(max(0.0, 1.0 + m33 - m11 - m22))
        q = ((m12 - m21) / s if s else 0.0, (m31 + m13) / s if s else 0.0,
             (m32 + m23) / s if s else 0.0, 0.25 * s)
    return _unit(q)


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> Quaternion:
    """The sensor's orientation in the earth frame from Euler angles in radians, as
    (w, x, y, z): the rotation q(yaw about z) . q(pitch about y) . q(roll about x)."""
    sr, cr = math.sin(roll / 2), math.cos(roll / 2)
    sp, cp = math.sin(pitch / 2), math.cos(pitch / 2)
    sy, cy = math.sin(yaw / 2), math.cos(yaw / 2)
    return _unit((cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                  cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy))


def _unit(q: Quaternion) -> Quaternion:
    """``q`` of length 1 with w >= 0; NaN where it has no length (or is not finite)."""
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if not 0.0 < norm < math.inf:
        return NAN_QUATERNION
    if q[0] < 0.0:
        norm = -norm
    return (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm)
