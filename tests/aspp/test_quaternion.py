"""The quaternion of a node's orientation: the sensor frame in the earth frame (M's
transpose), checked against cases worked by hand, against what it does to a vector, and
against the euler angles of the same instant of gx2-sim's body."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aspp.orientation import (
    euler_from_matrix,
    matrix_from_euler,
    quaternion_from_euler,
    quaternion_from_matrix,
)
from gateway.sim.physics import Motion, rotate, transpose

H = math.sqrt(0.5)
# (M as the node sends it, earth to sensor; the quaternion (w, x, y, z) worked by hand)
HAND_WORKED = {
    "identity": (((1, 0, 0), (0, 1, 0), (0, 0, 1)), (1, 0, 0, 0)),
    # rolled 90 degrees (right wing down): earth down is the sensor's +y
    "roll 90": (((1, 0, 0), (0, 0, 1), (0, -1, 0)), (H, H, 0, 0)),
    # pitched 90 degrees (nose up): earth down is the sensor's -x
    "pitch 90": (((0, 0, -1), (0, 1, 0), (1, 0, 0)), (H, 0, H, 0)),
    # yawed 90 degrees (nose east): earth east is the sensor's +x
    "yaw 90": (((0, 1, 0), (-1, 0, 0), (0, 0, 1)), (H, 0, 0, H)),
    # upside down about x: w = 0, the largest element is x
    "roll 180": (((1, 0, 0), (0, -1, 0), (0, 0, -1)), (0, 1, 0, 0)),
    "yaw 180": (((-1, 0, 0), (0, -1, 0), (0, 0, 1)), (0, 0, 0, 1)),
}


@pytest.mark.parametrize("case", HAND_WORKED)
def test_hand_worked_matrices(case: str) -> None:
    m, want = HAND_WORKED[case]
    assert quaternion_from_matrix(m) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("case", ["roll 90", "pitch 90", "yaw 90"])
def test_90_degrees_about_each_axis_from_the_euler_angles(case: str) -> None:
    angles = {"roll 90": (math.pi / 2, 0, 0), "pitch 90": (0, math.pi / 2, 0),
              "yaw 90": (0, 0, math.pi / 2)}[case]
    assert quaternion_from_euler(*angles) == pytest.approx(HAND_WORKED[case][1], abs=1e-12)


def test_a_known_euler_triple() -> None:
    """roll 30, pitch 45, yaw 60 degrees: q = qz(60) qy(45) qx(30), multiplied out by
    hand from the half-angles' sines and cosines."""
    c1, s1 = math.cos(math.radians(15)), math.sin(math.radians(15))  # roll / 2
    c2, s2 = math.cos(math.radians(22.5)), math.sin(math.radians(22.5))  # pitch / 2
    c3, s3 = math.cos(math.radians(30)), math.sin(math.radians(30))  # yaw / 2
    want = (c1 * c2 * c3 + s1 * s2 * s3, s1 * c2 * c3 - c1 * s2 * s3,
            c1 * s2 * c3 + s1 * c2 * s3, c1 * c2 * s3 - s1 * s2 * c3)
    assert want == pytest.approx((0.8223632, 0.0222600, 0.4396797, 0.3604234), abs=1e-7)
    angles = (math.radians(30), math.radians(45), math.radians(60))
    assert quaternion_from_euler(*angles) == pytest.approx(want, abs=1e-12)
    assert quaternion_from_matrix(matrix_from_euler(*angles)) == pytest.approx(want,
                                                                              abs=1e-12)


def rotated(q: tuple[float, float, float, float], v: tuple[float, ...]) -> list[float]:
    """``v`` turned by ``q`` (q v q*), written out."""
    w, x, y, z = q
    r = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
         (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
         (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))
    return [sum(r[i][k] * v[k] for k in range(3)) for i in range(3)]


angle = st.floats(-math.pi + 1e-6, math.pi - 1e-6)


@given(roll=angle, pitch=st.floats(-1.5, 1.5), yaw=angle)
def test_it_takes_sensor_coordinates_to_earth_coordinates(roll, pitch, yaw) -> None:
    """The frame Foxglove draws: q turns the sensor's axes into where they point on
    earth, M's transpose (M itself takes earth vectors into the sensor frame)."""
    m = matrix_from_euler(roll, pitch, yaw)
    q = quaternion_from_matrix(m)
    assert q[0] >= 0 and math.fsum(c * c for c in q) == pytest.approx(1.0, abs=1e-12)
    for axis in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
        assert rotated(q, axis) == pytest.approx(rotate(transpose(m), axis), abs=1e-9)
    assert quaternion_from_euler(roll, pitch, yaw) == pytest.approx(q, abs=1e-9)


def test_the_simulated_bodys_matrix_and_euler_angles_at_one_instant_agree() -> None:
    """gx2-sim's body gives both at every instant: the quaternion of its matrix is the
    quaternion of its euler angles, and of the angles read back from the matrix."""
    motion = Motion(roll=0.4, pitch=-0.3, yaw_rate=0.7, swing=0.5, swing_period=3.0)
    for t in (0.0, 0.37, 1.2, 2.9, 7.5, 13.1):
        m = motion.orientation(t)
        q = quaternion_from_matrix(m)
        assert quaternion_from_euler(*motion.euler(t)) == pytest.approx(q, abs=1e-9)
        assert quaternion_from_euler(*euler_from_matrix(m)) == pytest.approx(q, abs=1e-9)


def test_a_matrix_of_nan_gives_nan_and_never_raises() -> None:
    nan = math.nan
    assert all(math.isnan(c) for c in quaternion_from_matrix(((nan,) * 3,) * 3))
    assert all(math.isnan(c) for c in euler_from_matrix(((nan,) * 3,) * 3))
    for garbage in (((5.0,) * 3,) * 3, ((-2.0, 0, 0), (0, -2.0, 0), (0, 0, -2.0)),
                    ((1e30, -1e30, 0), (0, 0, 0), (0, 0, 0))):
        quaternion_from_matrix(garbage)  # (no rotation: any answer, but no exception)
