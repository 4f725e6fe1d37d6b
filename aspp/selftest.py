"""The built-in test (0xFB) judged: did every output step as the reference says?

Setting bit 4 of 0xFB's TestConfig steps every accelerometer and rate sensor output
positive ("a simulated inertial input"); bit 5 steps the rate sensors negative;
0x00 ends the test. The reference gives no step sizes, so a step passes when it is
both larger than a floor (MIN_ACCEL_STEP, MIN_RATE_STEP) and NOISE_MARGIN times the
noise of that output measured with BIT off. With the node still, the accelerometers
measure gravity alone: 1 g within GRAVITY_TOLERANCE. Temperatures must lie within the
sensors' operating range. Pure: the caller takes the samples and reads the
temperatures; :func:`judge` only decides.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from .fields import Vector

POSITIVE_BIT = 0x10
"""TestConfig bit 4: accelerometers and rate sensors stepped positive."""
NEGATIVE_RATE_BIT = 0x20
"""TestConfig bit 5: rate sensors stepped negative."""
BIT_OFF = 0x00
MIN_ACCEL_STEP = 0.05
"""g: the smallest step of an accelerometer under BIT that counts as a response."""
MIN_RATE_STEP = 0.05
"""rad/s (about 2.9 deg/s): the same for a rate sensor."""
NOISE_MARGIN = 6.0
"""A step must also exceed this many standard deviations of the output with BIT off."""
GRAVITY_TOLERANCE = 0.05
"""g: how far |accel| of a node standing still may be from 1 g."""
TEMPERATURE_RANGE = (-40.0, 85.0)
"""deg C: outside this a temperature sensor (or its conversion) is wrong."""
AXES = "xyz"


@dataclass(frozen=True)
class Sample:
    """One reading of the outputs BIT steps."""

    accel: Vector
    ang_rate: Vector


@dataclass(frozen=True)
class Check:
    """One line of the verdict: ``value`` must lie within ``low``..``high`` (None: no
    bound on that side)."""

    name: str
    value: float
    unit: str
    low: float | None = None
    high: float | None = None

    @property
    def passed(self) -> bool:
        return (not math.isnan(self.value)
                and (self.low is None or self.value >= self.low)
                and (self.high is None or self.value <= self.high))

    @property
    def limit(self) -> str:
        if self.low is not None and self.low == self.high:
            return f"= {self.low:g}"
        if self.low is not None and self.high is not None:
            return f"{self.low:g}..{self.high:g}"
        return f">= {self.low:g}" if self.low is not None else f"<= {self.high:g}"

    def as_dict(self) -> dict[str, object]:
        return {"name": self.name, "value": self.value, "unit": self.unit, "low": self.low,
                "high": self.high, "limit": self.limit, "passed": self.passed}


def _means(samples: Sequence[Sample], output: str) -> list[float]:
    return [statistics.fmean(getattr(s, output)[axis] for s in samples) for axis in range(3)]


def _noise(samples: Sequence[Sample], output: str) -> list[float]:
    if len(samples) < 2:
        return [0.0, 0.0, 0.0]
    return [statistics.stdev(getattr(s, output)[axis] for s in samples) for axis in range(3)]


def judge(off: Sequence[Sample], positive: Sequence[Sample], negative: Sequence[Sample],
          after: Sequence[Sample], temperatures_c: Sequence[float],
          bit_off_echo: int | None) -> list[Check]:
    """Every check of a self-test, in order: ``off`` with BIT off, ``positive`` with
    bit 4, ``negative`` with bit 5, ``after`` with BIT off again; the four temperatures
    (accelerometer, gyros x, y, z); the TestConfig echoed when BIT was switched off."""
    checks: list[Check] = []
    base = {o: _means(off, o) for o in ("accel", "ang_rate")}
    noise = {o: _noise(off, o) for o in ("accel", "ang_rate")}
    floor = {"accel": MIN_ACCEL_STEP, "ang_rate": MIN_RATE_STEP}
    unit = {"accel": "g", "ang_rate": "rad/s"}
    label = {"accel": "accel", "ang_rate": "rate"}

    def limit(output: str, axis: int) -> float:
        return max(floor[output], NOISE_MARGIN * noise[output][axis])

    for phase, samples, steps in (("bit4", positive, {"accel": 1, "ang_rate": 1}),
                                  ("bit5", negative, {"accel": 0, "ang_rate": -1})):
        for output, sign in steps.items():
            means = _means(samples, output)
            for axis in range(3):
                step = means[axis] - base[output][axis]
                least = limit(output, axis)
                name = f"{phase} {label[output]} {AXES[axis]}"
                if sign > 0:
                    checks.append(Check(f"{name} steps up", step, unit[output], low=least))
                elif sign < 0:
                    checks.append(Check(f"{name} steps down", step, unit[output],
                                        high=-least))
                else:
                    checks.append(Check(f"{name} does not step", step, unit[output],
                                        -least, least))
    checks.append(Check("gravity |accel| with BIT off", math.hypot(*base["accel"]), "g",
                        1 - GRAVITY_TOLERANCE, 1 + GRAVITY_TOLERANCE))
    for name, celsius in zip(("accel", "gyro x", "gyro y", "gyro z"), temperatures_c,
                             strict=True):
        checks.append(Check(f"temperature {name}", celsius, "deg C", *TEMPERATURE_RANGE))
    for output in ("accel", "ang_rate"):
        means = _means(after, output)
        worst = max(range(3), key=lambda axis: abs(means[axis] - base[output][axis]))
        least = limit(output, worst)
        checks.append(Check(f"BIT off again: {label[output]} {AXES[worst]} back",
                            means[worst] - base[output][worst], unit[output], -least, least))
    checks.append(Check("BIT off again: TestConfig echoed",
                        math.nan if bit_off_echo is None else float(bit_off_echo), "", 0, 0))
    return checks
