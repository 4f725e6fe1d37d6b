"""A slowly rotating rigid body: every quantity a GX2 reports, derived from one motion.

The body turns about the earth's vertical at a constant rate; its roll and pitch are
fixed (``turn``, the default) or swing about them (``swing``: roll and pitch a quarter
period apart, so the body wobbles round a cone and every axis of accel moves). Its
orientation M(t) is known exactly, as Euler angles of t, and everything else follows:
accel is gravity seen in the sensor frame (the body turns about the sensor itself, so
it measures -1 g along earth down, NED, and nothing else), the angular rate is the
Euler angles' rates seen in the sensor frame, the delta quantities are their
integrals over one sample period, and the magnetometer sees the earth's field. Tests
check these relations, so the simulator's values are physically consistent rather
than merely well-formed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
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
    """Roll and pitch about ``roll`` and ``pitch`` (swinging by ``swing`` rad, roll's
    amplitude, pitch's PITCH_SHARE of it, every ``swing_period`` s), yaw turning at
    ``yaw_rate`` rad/s from ``yaw0``."""

    roll: float = 0.05
    pitch: float = -0.03
    yaw0: float = 0.0
    yaw_rate: float = 0.2
    swing: float = 0.0
    swing_period: float = 4.0

    def _phase(self, t: float) -> tuple[float, float]:
        """(sin, cos) of the swing's phase at ``t``."""
        phase = math.tau * t / self.swing_period
        return math.sin(phase), math.cos(phase)

    def euler(self, t: float) -> tuple[float, float, float]:
        yaw = math.remainder(self.yaw0 + self.yaw_rate * t, math.tau)
        if not self.swing:
            return self.roll, self.pitch, yaw
        sine, cosine = self._phase(t)
        return (self.roll + self.swing * sine,
                self.pitch + self.swing * PITCH_SHARE * cosine, yaw)

    def euler_rates(self, t: float) -> tuple[float, float, float]:
        """d/dt of (roll, pitch, yaw), rad/s."""
        if not self.swing:
            return 0.0, 0.0, self.yaw_rate
        sine, cosine = self._phase(t)
        frequency = math.tau / self.swing_period
        return (self.swing * frequency * cosine,
                -self.swing * PITCH_SHARE * frequency * sine, self.yaw_rate)

    def orientation(self, t: float) -> Matrix:
        return matrix_from_euler(*self.euler(t))

    def accel(self, t: float) -> Vector:
        return rotate(self.orientation(t), EARTH_SPECIFIC_FORCE)

    def ang_rate(self, t: float) -> Vector:
        """The body's rotation in the sensor frame: the ZYX Euler angles' rates, each
        about its own axis (yaw about earth down, pitch about the axis after yaw, roll
        about the sensor's x), carried into the sensor frame."""
        roll, pitch, _ = self.euler(t)
        droll, dpitch, dyaw = self.euler_rates(t)
        sr, cr = math.sin(roll), math.cos(roll)
        sp, cp = math.sin(pitch), math.cos(pitch)
        return (droll - dyaw * sp,
                dpitch * cr + dyaw * sr * cp,
                -dpitch * sr + dyaw * cr * cp)

    def mag(self, t: float) -> Vector:
        return rotate(self.orientation(t), EARTH_FIELD)

    def orientation_update(self, t: float, period: float) -> Matrix:
        """C with M(t) = C . M(t - period): the change over the last cycle."""
        return multiply(self.orientation(t), transpose(self.orientation(t - period)))

    def delta_angle(self, t: float, period: float) -> Vector:
        """The angular rate's integral over the cycle ending at ``t``."""
        return _integral(self.ang_rate, t, period)

    def delta_velocity(self, t: float, period: float) -> Vector:
        """The acceleration's integral over the cycle ending at ``t`` (g s)."""
        return _integral(self.accel, t, period)


PITCH_SHARE = 0.6
"""Pitch's swing, a share of roll's: a quarter period apart, the two trace an ellipse."""
SWING = 0.35
"""A swinging node's roll amplitude, rad (20 degrees; pitch's 12)."""
MOTIONS = {"turn": Motion(), "swing": Motion(swing=SWING)}
"""The motions a simulated node can be given by name (gx2-sim's ``motion:``)."""


def _integral(rate: Callable[[float], Vector], t: float, period: float) -> Vector:
    """Simpson's rule over [t - period, t]: exact for a constant or a straight line,
    and within 1e-9 of the truth for a swing of a few seconds sampled at 100 Hz."""
    a, m, b = rate(t - period), rate(t - period / 2), rate(t)
    return (period * (a[0] + 4 * m[0] + b[0]) / 6, period * (a[1] + 4 * m[1] + b[1]) / 6,
            period * (a[2] + 4 * m[2] + b[2]) / 6)
