"""The GX2's frames and units as ROS expects them (REP-103): THE one conversion, used by
the ROS 2 export (:mod:`.rosbag`) and nowhere written again.

The GX2 gives its vectors (``accel``, ``ang_rate``, ``mag``) in its sensor frame, x
forward, y right, z down (FRD), and its orientation matrix M relative to the earth
frame, x north, y east, z down (NED), with V_sensor = M . V_earth (the reference's
definition; :mod:`aspp.orientation`). REP-103 wants a body frame x forward, y left,
z up (FLU) and a world frame x east, y north, z up (ENU). Both changes are fixed
reflections of axes, each its own inverse:

    FLU = B . FRD    B = diag(1, -1, -1)          (a half turn about x)
    ENU = W . NED    W = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]

A vector in the sensor frame becomes ``B . v``; the orientation, the body's frame in
the world's (the rotation that takes body coordinates to world coordinates, what ROS
calls ``orientation`` and a transform's ``rotation``), is ``R_ned = M^T`` for the
device and ``R_enu = W . M^T . B`` for REP-103. With ``frame="ned"`` nothing turns:
the vectors stay in the sensor frame and the orientation is ``M^T``, as the live view's
frames give it.

Units are SI, as ROS's messages say: accelerations in g times STANDARD_GRAVITY (the
reference's 9.80665 m/s^2), angular rates already in rad/s, the magnetometer's gauss
times 1e-4 (tesla).

Worked cases (docs/ros2.md has the table; tests/recording/test_rep103.py checks each):
a node lying flat facing north reads accel (0, 0, -1) g and M = I; in ENU/FLU its
acceleration is (0, 0, +9.80665) m/s^2 and its orientation a quarter turn about z
(its forward axis points north, ENU's +y): (w, x, y, z) = (0.7071, 0, 0, 0.7071).
Yawed to the east (yaw +90 degrees in NED), its forward axis is ENU's +x: the identity.
Rolled 90 degrees right wing down, facing north, it reads (0, -1, 0) g: in FLU (0,
+9.80665, 0), gravity's reaction along its left axis, which points up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from aspp.orientation import Quaternion, matrix_from_euler, quaternion_from_matrix

FRAMES = ("enu", "ned")
"""``enu``: REP-103's (ENU world, FLU body), the default; ``ned``: the device's own."""
STANDARD_GRAVITY = 9.80665
"""m/s^2 in one g: the reference's figure (its ``Accel`` is scaled by it)."""
TESLA_PER_GAUSS = 1e-4
WORLD = {"enu": "world", "ned": "world_ned"}
"""The world frame's name in ``/tf``: REP-103's ``_ned`` suffix for the device's own."""

Vector3 = tuple[float, float, float]
Rows = Sequence[Sequence[float]]

_B = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))
_W = ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0))


def _product(a: Rows, b: Rows) -> tuple[Vector3, Vector3, Vector3]:
    return tuple(tuple(sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3))
                 for i in range(3))  # type: ignore[return-value]


def body(vector: Sequence[float], frame: str) -> Vector3:
    """A vector of the sensor frame (FRD) in the body frame asked: FLU for ``enu``, the
    sensor's own for ``ned``."""
    x, y, z = (float(v) for v in vector)
    return (x, -y, -z) if frame == "enu" else (x, y, z)


def acceleration(accel_g: Sequence[float], frame: str) -> Vector3:
    """``accel`` (g, sensor frame) as ``linear_acceleration`` (m/s^2, body frame)."""
    x, y, z = body(accel_g, frame)
    return (x * STANDARD_GRAVITY, y * STANDARD_GRAVITY, z * STANDARD_GRAVITY)


def magnetic_field(mag_gauss: Sequence[float], frame: str) -> Vector3:
    """``mag`` (gauss, sensor frame) as ``magnetic_field`` (tesla, body frame)."""
    x, y, z = body(mag_gauss, frame)
    return (x * TESLA_PER_GAUSS, y * TESLA_PER_GAUSS, z * TESLA_PER_GAUSS)


def rotation(matrix: Rows, frame: str) -> tuple[Vector3, Vector3, Vector3]:
    """The rotation taking body coordinates to world coordinates, from the GX2's M:
    ``W . M^T . B`` for ``enu``, ``M^T`` for ``ned``."""
    transposed = tuple(tuple(float(matrix[j][i]) for j in range(3)) for i in range(3))
    if frame != "enu":
        return transposed  # type: ignore[return-value]
    return _product(_W, _product(transposed, _B))


def orientation(matrix: Rows, frame: str) -> Quaternion:
    """The body's orientation in the world as a unit quaternion (w, x, y, z), w >= 0;
    NaN from a matrix with a NaN."""
    turned = rotation(matrix, frame)
    # quaternion_from_matrix takes the GX2's M (world to body): the transpose of ours
    return quaternion_from_matrix(tuple(tuple(turned[j][i] for j in range(3))
                                        for i in range(3)))  # type: ignore[arg-type]


def orientation_of_euler(roll: float, pitch: float, yaw: float, frame: str) -> Quaternion:
    """The same from the GX2's Euler angles (radians; the reference's ZYX set)."""
    return orientation(matrix_from_euler(roll, pitch, yaw), frame)


def finite(values: Sequence[float]) -> bool:
    """Whether every value is a finite number (an Inertia-Link's magnetometer is NaN)."""
    return all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)
