"""Euler <-> matrix and the temperature conversions, against the reference's formulas
(and its gyro temperature erratum)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aspp.orientation import euler_from_matrix, matrix_from_euler
from aspp.temperature import GYRO_NAMES, accel_celsius, accel_code, gyro_celsius, gyro_code


def test_identity_is_level_and_north():
    assert matrix_from_euler(0, 0, 0) == ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    assert euler_from_matrix(((1, 0, 0), (0, 1, 0), (0, 0, 1))) == (0, 0, 0)


def test_pure_yaw_follows_the_reference_matrix():
    m = matrix_from_euler(0, 0, math.pi / 2)
    expected = ((0, 1, 0), (-1, 0, 0), (0, 0, 1))
    for row, want in zip(m, expected, strict=True):
        assert row == pytest.approx(want, abs=1e-12)


angles = st.floats(-math.pi + 1e-6, math.pi - 1e-6)


@given(roll=angles, pitch=st.floats(-1.5, 1.5), yaw=angles)
def test_euler_matrix_round_trip_and_orthonormal(roll, pitch, yaw):
    m = matrix_from_euler(roll, pitch, yaw)
    for i in range(3):
        for j in range(3):
            dot = sum(m[i][k] * m[j][k] for k in range(3))
            assert dot == pytest.approx(1.0 if i == j else 0.0, abs=1e-12)
    assert euler_from_matrix(m) == pytest.approx((roll, pitch, yaw), abs=1e-9)


def test_pitch_clamped_at_the_singularity():
    m = ((0.0, 0.0, -1.0000001), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
    assert euler_from_matrix(m)[1] == pytest.approx(math.pi / 2)


def test_temperature_conversions():
    # 0.5 V is 0 deg C on the board sensor: 0.5 / (3.3/4096) = 620.6 codes
    assert accel_celsius(621) == pytest.approx(0.03, abs=0.01)
    assert accel_celsius(accel_code(25.0)) == pytest.approx(25.0, abs=0.1)
    # ADXRS610: 2.5 V at 25 deg C
    assert gyro_celsius(round(2.5 / (3.3 / 4096))) == pytest.approx(25.0, abs=0.1)
    # ADXRS300: 8.4 mV/K, so a room-temperature part reads near 2.5 V and ~25 deg C
    # (with the reference's printed "+ 273" it would read about 570 deg C)
    assert gyro_celsius(3103, "ADXRS300") == pytest.approx(24.6, abs=0.5)
    for model in GYRO_NAMES:
        assert gyro_celsius(gyro_code(40.0, model), model) == pytest.approx(40.0, abs=0.2)
    with pytest.raises(ValueError, match="gyro model"):
        gyro_celsius(100, "MPU6050")
