"""A slowly rotating rigid body: every quantity a GX2 reports, derived from one motion.

The body turns about the earth's vertical at a constant rate while its roll and pitch
are fixed, so its orientation M(t) is known exactly and everything else follows:
accel is gravity seen in the sensor frame (a body at rest measures -1 g along earth
down, NED), the angular rate is the earth rate seen in the sensor frame, the delta
quantities are their integrals over one sample period, and the magnetometer sees the
earth's field. Tests check these relations, so the simulator's values are physically
consistent rather than merely well-formed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from aspp.fields import Matrix, Vector
from aspp.orientation import matrix_from_euler

EARTH_SPECIFIC_FORCE: Vector = (0.0, 0.0, -1.0)
"""What an accelerometer at rest measures, in g, in earth axes (north, east, down)."""
EARTH_FIELD: Vector = (0.21, -0.01, 0.43)
"""A mid-latitude geomagnetic field in gauss, earth axes."""


def rotate(m: Matrix, v: Vector) -> Vector:
    """M . v: an earth-frame vector in the sensor frame."""
    return (m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2])


def multiply(a: Matrix, b: Matrix) -> Matrix:
    return tuple(tuple(sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3))
                 for i in range(3))  # type: ignore[return-value]


def transpose(m: Matrix) -> Matrix:
    return tuple(tuple(m[j][i] for j in range(3)) for i in range(3))  # type: ignore[return-value]


@dataclass(frozen=True)
class Motion:
    """Fixed roll and pitch, yaw turning at ``yaw_rate`` rad/s from ``yaw0``."""

    roll: float = 0.05
    pitch: float = -0.03
    yaw0: float = 0.0
    yaw_rate: float = 0.2

    def euler(self, t: float) -> tuple[float, float, float]:
        yaw = math.remainder(self.yaw0 + self.yaw_rate * t, math.tau)
        return self.roll, self.pitch, yaw

    def orientation(self, t: float) -> Matrix:
        return matrix_from_euler(*self.euler(t))

    def accel(self, t: float) -> Vector:
        return rotate(self.orientation(t), EARTH_SPECIFIC_FORCE)

    def ang_rate(self, t: float) -> Vector:
        """The body's rotation (about earth down) expressed in the sensor frame."""
        return rotate(self.orientation(t), (0.0, 0.0, self.yaw_rate))

    def mag(self, t: float) -> Vector:
        return rotate(self.orientation(t), EARTH_FIELD)

    def orientation_update(self, t: float, period: float) -> Matrix:
        """C with M(t) = C . M(t - period): the change over the last cycle."""
        return multiply(self.orientation(t), transpose(self.orientation(t - period)))

    def delta_angle(self, t: float, period: float) -> Vector:
        rate = self.ang_rate(t)  # constant in the sensor frame for this motion
        return (rate[0] * period, rate[1] * period, rate[2] * period)

    def delta_velocity(self, t: float, period: float) -> Vector:
        accel = self.accel(t)  # constant too: the rotation is about the vertical
        return (accel[0] * period, accel[1] * period, accel[2] * period)
