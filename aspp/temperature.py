"""The four temperature sensors (0xD1): A/D codes to degrees Celsius and back.

All four are read by a 12-bit converter on a 3.3 V reference. The board sensor beside
the accelerometers is the accurate one: T = (V - 0.5) * 100. Each gyro's own output is
repeatable rather than accurate, and its conversion depends on the rate sensor model:

- ADXRS150, ADXRS300, ADXRS401: 8.4 mV per kelvin, T = V / 0.0084 - 273. The reference
  prints ``+ 273``, an erratum: it would put a part at room temperature near 570 deg C.
  (It also writes the accelerometer's code into both gyro formulas; each gyro's own
  code is meant.)
- ADXRS610, ADXRS612, ADXRS614: 2.5 V at 25 deg C and 9 mV per deg C,
  T = (V - 2.5) / 0.009 + 25.
"""

from __future__ import annotations

from dataclasses import dataclass

VOLTS_PER_CODE = 3.3 / 4096


@dataclass(frozen=True)
class GyroModel:
    """A rate sensor's temperature output: volts = offset + slope * deg C."""

    names: tuple[str, ...]
    offset: float
    slope: float


GYRO_MODELS = (GyroModel(("ADXRS150", "ADXRS300", "ADXRS401"), 273 * 0.0084, 0.0084),
               GyroModel(("ADXRS610", "ADXRS612", "ADXRS614"), 2.5 - 25 * 0.009, 0.009))
GYRO_NAMES = tuple(name for model in GYRO_MODELS for name in model.names)
DEFAULT_GYRO = "ADXRS610"
"""The rate sensors of the nodes built with the firmware this gateway speaks to (2.1.x);
the older ADXRS150/300 parts read about 570 deg C through this conversion, which is how
to tell that a node needs ``gyro: ADXRS300``."""


def gyro_model(name: str) -> GyroModel:
    for model in GYRO_MODELS:
        if name in model.names:
            return model
    raise ValueError(f"unknown gyro model {name!r}; known: {', '.join(GYRO_NAMES)}")


def accel_celsius(code: int) -> float:
    """The board sensor beside the accelerometers, the most accurate of the four."""
    return (code * VOLTS_PER_CODE - 0.5) * 100


def gyro_celsius(code: int, gyro: str = DEFAULT_GYRO) -> float:
    model = gyro_model(gyro)
    return (code * VOLTS_PER_CODE - model.offset) / model.slope


def accel_code(celsius: float) -> int:
    """The A/D code a board sensor at ``celsius`` reads (the inverse, for gx2-sim)."""
    return round((celsius / 100 + 0.5) / VOLTS_PER_CODE)


def gyro_code(celsius: float, gyro: str = DEFAULT_GYRO) -> int:
    """The A/D code a gyro at ``celsius`` reads (the inverse, for gx2-sim)."""
    model = gyro_model(gyro)
    return round((model.offset + model.slope * celsius) / VOLTS_PER_CODE)
