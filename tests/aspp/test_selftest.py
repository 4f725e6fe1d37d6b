"""The built-in test's verdict on outputs with known faults: a healthy node passes
every check, and each kind of fault fails exactly the checks it should."""

from __future__ import annotations

import random

import pytest

from aspp.selftest import MIN_ACCEL_STEP, NOISE_MARGIN, Sample, judge

GRAVITY = (0.02, -0.03, -0.9994)
STILL = (0.001, -0.002, 0.0005)
TEMPERATURES = (24.8, 27.9, 28.3, 27.5)


def samples(accel_step=(0.0, 0.0, 0.0), rate_step=(0.0, 0.0, 0.0), count: int = 10,
            noise: float = 0.002, seed: int = 1) -> list[Sample]:
    rng = random.Random(seed)
    return [Sample(tuple(g + s + rng.gauss(0, noise) for g, s in zip(GRAVITY, accel_step,
                                                                      strict=True)),
                   tuple(r + s + rng.gauss(0, noise) for r, s in zip(STILL, rate_step,
                                                                     strict=True)))
            for _ in range(count)]


def healthy(**change) -> dict:
    parts = {"off": samples(seed=1), "positive": samples((0.1,) * 3, (0.1,) * 3, seed=2),
             "negative": samples(rate_step=(-0.1,) * 3, seed=3), "after": samples(seed=4),
             "temperatures_c": TEMPERATURES, "bit_off_echo": 0}
    return {**parts, **change}


def failed(**change) -> list[str]:
    return [c.name for c in judge(**healthy(**change)) if not c.passed]


def test_a_healthy_node_passes_every_check() -> None:
    checks = judge(**healthy())
    assert len(checks) == 20 and all(c.passed for c in checks), \
        [c for c in checks if not c.passed]


def test_an_axis_that_does_not_step_fails_its_check_alone() -> None:
    assert failed(positive=samples((0.1, 0.1, 0.1), (0.1, 0.0, 0.1), seed=2)) == \
        ["bit4 rate y steps up"]
    assert failed(negative=samples(rate_step=(-0.1, -0.1, 0.1), seed=3)) == \
        ["bit5 rate z steps down"]
    assert failed(negative=samples((0.2, 0, 0), (-0.1,) * 3, seed=3)) == \
        ["bit5 accel x does not step"]


def test_a_step_must_stand_above_the_noise() -> None:
    """With noisy outputs, a step of the floor's size is not enough: the limit is
    NOISE_MARGIN times the noise measured with BIT off."""
    noisy = 0.02
    assert NOISE_MARGIN * noisy > MIN_ACCEL_STEP
    off = samples(noise=noisy, count=40, seed=1)
    small = samples((0.06,) * 3, (0.5,) * 3, noise=noisy, count=40, seed=2)
    names = failed(off=off, positive=small, negative=samples(rate_step=(-0.5,) * 3,
                                                             noise=noisy, count=40, seed=3),
                   after=samples(noise=noisy, count=40, seed=4))
    assert names == ["bit4 accel x steps up", "bit4 accel y steps up",
                     "bit4 accel z steps up"]


def test_gravity_temperatures_and_bit_left_on_are_caught() -> None:
    assert failed(off=[Sample((0, 0, -0.8), STILL)] * 10, positive=[
        Sample((0.1, 0.1, -0.7), (0.101, 0.098, 0.1005))] * 10, negative=[
        Sample((0, 0, -0.8), (-0.099, -0.102, -0.0995))] * 10,
        after=[Sample((0, 0, -0.8), STILL)] * 10) == ["gravity |accel| with BIT off"]
    # the ADXRS300's formula as the reference prints it: a gyro "at" 570 deg C
    assert failed(temperatures_c=(24.8, 570.6, 28.3, 27.5)) == ["temperature gyro x"]
    still_on = failed(after=samples((0.1,) * 3, (0.1,) * 3, seed=4))
    assert [name.split()[3] for name in still_on] == ["accel", "rate"], still_on
    assert failed(bit_off_echo=None) == ["BIT off again: TestConfig echoed"]
    assert failed(bit_off_echo=0x10) == ["BIT off again: TestConfig echoed"]


@pytest.mark.parametrize("check", judge(**healthy())[:3])
def test_a_check_says_its_limit(check) -> None:
    assert check.limit.startswith(">= ") and check.as_dict()["passed"] is True
