"""Orientation conversions, as the reference's formulas give them.

M maps earth-frame vectors into the sensor frame (V_sensor = M . V_earth). Euler angles
are the "aircraft" ZYX set: pitch = asin(-M13), roll = atan2(M23, M33),
yaw = atan2(M12, M11). Pitch is singular at +/-90 degrees; the matrix is not.
"""

from __future__ import annotations

import math

from .fields import Matrix


def euler_from_matrix(m: Matrix) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians from the orientation matrix M."""
    pitch = math.asin(max(-1.0, min(1.0, -m[0][2])))
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
