"""Orientation and temperature conversions, as the reference's formulas give them.

M maps earth-frame vectors into the sensor frame (V_sensor = M . V_earth). Euler angles
are the "aircraft" ZYX set: pitch = asin(-M13), roll = atan2(M23, M33),
yaw = atan2(M12, M11). Pitch is singular at +/-90 degrees; the matrix is not.
"""

from __future__ import annotations

import math

from .fields import Matrix

ADC_VOLTS_PER_CODE = 3.3 / 4096
"""The temperature sensors' 12-bit converter on a 3.3 V reference."""


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


def accel_temperature_c(code: int) -> float:
    """The board sensor beside the accelerometers, the most accurate of the four."""
    return (code * ADC_VOLTS_PER_CODE - 0.5) * 100


def gyro_temperature_c(code: int, gyro: str = "ADXRS610") -> float:
    """A gyro's own temperature output: repeatable rather than accurate.

    ``gyro``: the rate sensor model. The ADXRS300/150/401 give 8.4 mV per kelvin, so
    T = V / 0.0084 - 273 (the reference prints "+ 273", an erratum: it would put a
    room-temperature part near 570 deg C). The ADXRS610/612/614 give 2.5 V at 25 deg C
    and 9 mV per deg C.
    """
    volts = code * ADC_VOLTS_PER_CODE
    if gyro in ("ADXRS300", "ADXRS150", "ADXRS401"):
        return volts / 0.0084 - 273
    if gyro in ("ADXRS610", "ADXRS612", "ADXRS614"):
        return (volts - 2.5) / 0.009 + 25
    raise ValueError(f"unknown gyro model {gyro!r}: ADXRS150, 300, 401, 610, 612 or 614")


def accel_temperature_code(celsius: float) -> int:
    """The A/D code a board sensor at ``celsius`` reads (inverse, for the simulator)."""
    return round((celsius / 100 + 0.5) / ADC_VOLTS_PER_CODE)


def gyro_temperature_code(celsius: float, gyro: str = "ADXRS610") -> int:
    """The A/D code a gyro at ``celsius`` reads (inverse, for the simulator)."""
    if gyro in ("ADXRS300", "ADXRS150", "ADXRS401"):
        volts = (celsius + 273) * 0.0084
    elif gyro in ("ADXRS610", "ADXRS612", "ADXRS614"):
        volts = (celsius - 25) * 0.009 + 2.5
    else:
        raise ValueError(f"unknown gyro model {gyro!r}: ADXRS150, 300, 401, 610, 612 or 614")
    return round(volts / ADC_VOLTS_PER_CODE)
