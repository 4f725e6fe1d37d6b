"""A swinging simulated node (``motion: swing``, the demo's): its records move, and
agree with one another as a rigid body's must: accel is gravity in the sensor frame,
the angular rate integrates to the orientation's change, the Euler angles are the
orientation's. The default motion (a turn about the vertical) stays as it was."""

from __future__ import annotations

import math

import pytest

from aspp import decode
from aspp.orientation import euler_from_matrix
from gateway.sim.config import SimConfig, SimNodeEntry, from_url
from gateway.sim.node import GX2, NodeSettings, SimNode
from gateway.sim.physics import MOTIONS, Motion, multiply, rotate, transpose
from tests.e2e.test_service import demo_sections

T0 = 1000.0
PERIOD = 0.01
SECONDS = 4.0  # one whole swing


def swinging() -> SimNode:
    return SimNode(NodeSettings(76, model=GX2, ppm=0.0, motion=MOTIONS["swing"]), now=T0)


def norm(v) -> float:
    return math.sqrt(sum(x * x for x in v))


def turned(delta: tuple[float, float, float]):
    """The change of an earth-to-sensor matrix over a turn of the body by ``delta``
    (rad, sensor axes): the sensor frame turns by ``delta``, so vectors seen in it
    turn by minus that (Rodrigues' formula)."""
    angle = norm(delta)
    x, y, z = (-d / angle for d in delta)
    c, s, k = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return ((c + x * x * k, x * y * k - z * s, x * z * k + y * s),
            (y * x * k + z * s, c + y * y * k, y * z * k - x * s),
            (z * x * k - y * s, z * y * k + x * s, c + z * z * k))


def test_a_swinging_nodes_records_move_and_agree_with_one_another():
    sim = swinging()
    times = [T0 + i * PERIOD for i in range(1, int(SECONDS / PERIOD) + 1)]
    full = [decode(sim.record(0xCC, t)) for t in times]  # accel, rate, mag, orientation
    accel = [r["accel"] for r in full]
    # every axis moves (the live view's recipe plots accel[0..2]): x and y by tenths of
    # g, z (near -1 g, tilted 20 degrees at most) by hundredths
    for axis, least in enumerate((0.3, 0.6, 0.05)):
        values = [a[axis] for a in accel]
        assert max(values) - min(values) > least, axis
    # at rest apart from turning about itself: 1 g, gravity as the orientation sees it
    for row in full:
        assert norm(row["accel"]) == pytest.approx(1.0, abs=1e-6)
        assert row["accel"] == pytest.approx(rotate(row["orientation"], (0, 0, -1)), abs=1e-6)
    # the angular rate, integrated cycle by cycle (delta angle), carries the first
    # orientation to the last; the rate itself is the delta angle's mean
    orientation = full[0]["orientation"]
    for t in times[1:]:
        delta = decode(sim.record(0xC3, t))["delta_angle"]
        orientation = multiply(turned(delta), orientation)
    for got, want in zip(orientation, full[-1]["orientation"], strict=True):
        assert got == pytest.approx(want, abs=2e-4)
    rates = [r["ang_rate"] for r in full]
    assert max(norm(r) for r in rates) > 0.4  # the swing, not only the slow turn
    # the Euler record is the orientation's angles, and they swing (roll and pitch)
    euler = [decode(sim.record(0xCE, t)) for t in times]
    for row, angles in zip(full, euler, strict=True):
        assert (angles["roll"], angles["pitch"], angles["yaw"]) == pytest.approx(
            euler_from_matrix(row["orientation"]), abs=1e-5)
    for name, amplitude in (("roll", MOTIONS["swing"].swing),
                            ("pitch", 0.6 * MOTIONS["swing"].swing)):
        values = [e[name] for e in euler]
        assert max(values) - min(values) == pytest.approx(2 * amplitude, rel=0.02), name
    # the update matrix carries each cycle's orientation to the next
    for before, after, t in zip(full, full[1:], times[1:], strict=False):
        update = decode(sim.record(0xC6, t))["orientation_update"]
        for got, want in zip(multiply(update, before["orientation"]), after["orientation"],
                             strict=True):
            assert got == pytest.approx(want, abs=1e-5)
        assert multiply(update, transpose(update))[0][0] == pytest.approx(1.0, abs=1e-5)


def test_the_default_motion_still_turns_about_the_vertical_only():
    sim = SimNode(NodeSettings(76, ppm=0.0), now=T0)
    assert sim.settings.motion == Motion() and not Motion().swing
    accel = {decode(sim.record(0xC2, T0 + i * PERIOD))["accel"] for i in range(1, 200)}
    assert len({tuple(round(v, 5) for v in a) for a in accel}) == 1


def test_the_swing_is_chosen_per_node_in_gx2_sim_and_for_every_node_in_sim_urls():
    assert SimNodeEntry(address=76, motion="swing").build().motion == MOTIONS["swing"]
    assert SimNodeEntry(address=76).build().motion == Motion()
    with pytest.raises(ValueError, match="must be turn or swing, not 'wobble'"):
        SimNodeEntry(address=76, motion="wobble")
    config = from_url("sim://?motion=swing&data_loss=0.01", [76, 77])
    assert [n.build().motion for n in config.nodes] == [MOTIONS["swing"]] * 2
    with pytest.raises(ValueError, match="wobble"):
        from_url("sim://?motion=wobble", [76])


def test_a_base_station_that_leaves_gaps_is_asked_for_in_a_sim_url_or_file():
    line = from_url("sim://?throughput=0.906&buffer_bytes=16384", [76]).line.build()
    assert (line.throughput, line.buffer_bytes) == (0.906, 16384)
    assert SimConfig.model_validate({"line": {"buffer_bytes": None}}).line.build() \
        .buffer_bytes is None
    for bad in ("throughput=0", "throughput=1.5", "buffer_bytes=0"):
        with pytest.raises(ValueError, match=bad.split("=")[0]) as said:
            from_url(f"sim://?{bad}", [76])
        assert "\n" not in str(said.value)


def test_the_demos_accel_moves_as_the_live_views_recipe_plots_it(gateway):
    # config/demo.yaml through the gateway: node 76's accel_angrate, accel[0..2]
    port, nodes, sections = demo_sections()
    gw = gateway(port, nodes, **sections)
    sub = gw.subscribe("gx2/76/accel_angrate")
    sub.until(lambda m: len(m) >= 200, 10, "two seconds of node 76's accel_angrate")
    accel = [p["accel"] for _, p in sub.messages]
    # over half a swing, whatever its phase, x and y move by a tenth of g or more
    # (z, near -1 g, by hundredths over a whole swing)
    for axis in range(2):
        values = [a[axis] for a in accel]
        assert max(values) - min(values) > 0.1, (axis, values[:5])
    assert all(norm(a) == pytest.approx(1.0, abs=1e-3) for a in accel)
