"""The GX2's frames into REP-103's (gateway/recording/rep103.py), on cases worked by
hand: a node lying flat facing north, yawed to the east, the south and the west,
rolled 90 degrees right wing down, pitched 90 degrees nose up; what it measures there
(gravity's reaction, 1 g up; the earth's field) and its orientation, each written out
from the picture of the node, not computed from the module's formulas. docs/ros2.md's
table of axes says the same."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aspp.orientation import matrix_from_euler
from gateway.recording import rep103
from gateway.recording.rosbag import ros_name

H = math.sqrt(0.5)
G = 9.80665
DEG = math.pi / 180
FIELD_NED = (0.21, -0.01, 0.43)  # gauss: north, east, down (a mid-latitude field)


def same_rotation(got, want) -> None:
    """q and -q are one rotation."""
    sign = 1 if sum(a * b for a, b in zip(got, want, strict=True)) >= 0 else -1
    assert [sign * v for v in got] == pytest.approx(want, abs=1e-12)


def sensor(m, v):
    """What the sensor reads of an earth-frame (NED) vector: M . v."""
    return tuple(sum(m[i][k] * v[k] for k in range(3)) for i in range(3))


# (roll, pitch, yaw) in degrees -> the orientation in ENU/FLU (w, x, y, z), and the
# world direction (ENU) of the body's forward, left and up axes
CASES = {
    "flat, facing north": ((0, 0, 0), (H, 0, 0, H),
                           ((0, 1, 0), (-1, 0, 0), (0, 0, 1))),
    "flat, yawed to the east": ((0, 0, 90), (1, 0, 0, 0),
                                ((1, 0, 0), (0, 1, 0), (0, 0, 1))),
    "flat, yawed to the south": ((0, 0, 180), (H, 0, 0, -H),
                                 ((0, -1, 0), (1, 0, 0), (0, 0, 1))),
    "flat, yawed to the west": ((0, 0, -90), (0, 0, 0, 1),
                                ((-1, 0, 0), (0, -1, 0), (0, 0, 1))),
    # right wing down: its left side faces up, its top faces east
    "rolled 90 degrees, facing north": ((90, 0, 0), (0.5, 0.5, 0.5, 0.5),
                                        ((0, 1, 0), (0, 0, 1), (1, 0, 0))),
    # nose up: its top faces back, south; its left side still west
    "pitched 90 degrees nose up, facing north": ((0, 90, 0), (0.5, 0.5, -0.5, 0.5),
                                                 ((0, 0, 1), (-1, 0, 0), (0, -1, 0))),
}


@pytest.mark.parametrize("case", CASES)
def test_orientation_in_rep103_frames_as_worked_by_hand(case: str) -> None:
    (roll, pitch, yaw), quaternion, axes = CASES[case]
    m = matrix_from_euler(roll * DEG, pitch * DEG, yaw * DEG)
    same_rotation(rep103.orientation(m, "enu"), quaternion)
    same_rotation(rep103.orientation_of_euler(roll * DEG, pitch * DEG, yaw * DEG, "enu"),
                  quaternion)
    turned = rep103.rotation(m, "enu")
    for column, world in enumerate(axes):  # body axis -> its direction in the world
        assert [turned[row][column] for row in range(3)] == pytest.approx(world, abs=1e-12)


# what the accelerometer reads at rest (g, sensor frame) -> m/s^2 in FLU
READINGS = {
    "flat, facing north": ((0, 0, 0), (0, 0, -1), (0, 0, G)),
    "rolled 90 degrees, facing north": ((90, 0, 0), (0, -1, 0), (0, G, 0)),
    "pitched 90 degrees nose up, facing north": ((0, 90, 0), (1, 0, 0), (G, 0, 0)),
}


@pytest.mark.parametrize("case", READINGS)
def test_gravitys_reaction_is_up_in_the_body_frame(case: str) -> None:
    (roll, pitch, yaw), reads, flu = READINGS[case]
    m = matrix_from_euler(roll * DEG, pitch * DEG, yaw * DEG)
    # the reading worked by hand is what the device reads there (M . (0, 0, -1 g))
    assert sensor(m, (0, 0, -1)) == pytest.approx(reads, abs=1e-12)
    assert rep103.acceleration(reads, "enu") == pytest.approx(flu, abs=1e-12)
    assert rep103.acceleration(reads, "ned") == pytest.approx(
        [v * G for v in reads], abs=1e-12)


def test_rates_and_the_field_of_a_node_flat_facing_north() -> None:
    # turning clockwise seen from above (yaw growing, toward the east): +z down in the
    # sensor's frame, -z up in FLU (ROS: a negative turn about z)
    assert rep103.body((0.0, 0.0, 0.5), "enu") == (0.0, -0.0, -0.5)
    assert rep103.body((0.0, 0.0, 0.5), "ned") == (0.0, 0.0, 0.5)
    # the field, north 0.21 G, east -0.01 G, down 0.43 G, read flat facing north:
    # forward 0.21, left +0.01, up -0.43 G; in tesla
    assert rep103.magnetic_field(FIELD_NED, "enu") == pytest.approx(
        (2.1e-5, 1e-6, -4.3e-5), abs=1e-15)
    assert rep103.magnetic_field(FIELD_NED, "ned") == pytest.approx(
        (2.1e-5, -1e-6, 4.3e-5), abs=1e-15)


def test_ned_keeps_the_devices_orientation() -> None:
    # flat facing north: no turn at all; yawed to the east: a quarter turn about down
    same_rotation(rep103.orientation(matrix_from_euler(0, 0, 0), "ned"), (1, 0, 0, 0))
    same_rotation(rep103.orientation(matrix_from_euler(0, 0, math.pi / 2), "ned"),
                  (H, 0, 0, H))
    assert rep103.WORLD == {"enu": "world", "ned": "world_ned"}


def test_a_nan_matrix_gives_no_orientation() -> None:
    m = ((math.nan,) * 3,) * 3
    assert not rep103.finite(rep103.orientation(m, "enu"))


angle = st.floats(-math.pi, math.pi)


@given(angle, st.floats(-1.5, 1.5), angle,
       st.tuples(*(st.floats(-2, 2),) * 3))
def test_a_vector_turned_into_the_world_is_the_same_in_either_frames(
        roll: float, pitch: float, yaw: float, earth: tuple[float, float, float]) -> None:
    """Any orientation, any earth vector (NED): read by the sensor, carried into FLU and
    turned into the world by the ENU orientation, it is the earth vector in ENU."""
    m = matrix_from_euler(roll, pitch, yaw)
    read = sensor(m, earth)
    turned = rep103.rotation(m, "enu")
    flu = rep103.body(read, "enu")
    world = [sum(turned[i][k] * flu[k] for k in range(3)) for i in range(3)]
    north, east, down = earth
    assert world == pytest.approx([east, north, -down], abs=1e-9)


@pytest.mark.parametrize(("name", "address", "token"), [
    ("left-wing", 76, "left_wing"), (None, 77, "gx2_77"), ("tail", 95, "tail"),
    ("2nd node", 5, "gx2_2nd_node"), ("--", 9, "gx2_9"), ("Hüfte links", 3, "H_fte_links")])
def test_a_nodes_name_as_a_ros_name(name: str | None, address: int, token: str) -> None:
    assert ros_name(name, address) == token


def test_gx2ctls_choices_are_the_librarys() -> None:
    """gx2ctl's parser names the formats and frames without importing the exporter (its
    start stays light): the same as the library's tables."""
    from gateway.ctl import offline
    from gateway.recording import export

    assert offline.FORMATS == export.FORMATS
    assert set(export.FORMATS) == {*export.WRITERS, *export.WHOLE}
    assert offline.FRAMES == rep103.FRAMES
