"""The simulated node, without a port: its replies decoded by aspp and checked against
the physics and the reference's rules (cycles, combined order, EEPROM, power-up)."""

from __future__ import annotations

import math
from itertools import pairwise

import pytest

from aspp import commands, decode
from aspp.orientation import euler_from_matrix
from aspp.records import STREAMABLE, all_specs
from aspp.timing import TICKS_PER_SECOND, TIMER_MODULUS
from gateway.sim.node import GX2, INERTIA_LINK, NodeSettings, SimNode
from gateway.sim.physics import EARTH_FIELD, Motion, multiply, rotate

T0 = 1000.0


def node(**settings) -> SimNode:
    """Node 76 with a perfect crystal unless told otherwise: these tests count ticks."""
    return SimNode(NodeSettings(**{"address": 76, "ppm": 0.0, **settings}), now=T0)


def norm(v) -> float:
    return math.sqrt(sum(x * x for x in v))


def polled(sim: SimNode, command, at: float = T0 + 1.0):
    """Send one command and run the node long enough to answer it."""
    sim.receive(command.data)
    return [decode(reply) for _, reply in sim.run_until(at)]


@pytest.mark.parametrize("code", sorted(STREAMABLE), ids=lambda c: f"0x{c:02X}")
def test_every_data_record_decodes_with_its_contract_name(code):
    sim = node(model=GX2)
    record = decode(sim.record(code, T0 + 0.5))
    assert record.command == code
    assert record.timer == round(0.5 * TICKS_PER_SECOND)


def test_every_command_of_the_reference_is_answered_as_defined():
    """Each command with a reply gets exactly one record with the same echo byte."""
    args = {"continuous_command": 0xC2, "accel_bias": (0.01, 0, 0), "gyro_bias": (0, 0, 0),
            "sampling_time": 100, "quantity": 2, "address": 0xFCA2, "value": 256,
            "selector": 1, "test_config": 0}
    for spec in all_specs():
        if spec.reply is None:
            continue
        sim = node()
        command = commands.build(spec.code, **{f.name: args[f.name] for f in spec.arguments})
        replies = [r for r in polled(sim, command) if r.command == spec.code]
        assert len(replies) == 1, spec.name


def test_values_are_physically_consistent():
    sim = node(model=GX2)
    t, period = T0 + 12.3, sim.period
    full = decode(sim.record(0xCC, t))
    m = full["orientation"]
    for i in range(3):
        for j in range(3):
            dot = sum(m[i][k] * m[j][k] for k in range(3))
            assert dot == pytest.approx(1.0 if i == j else 0.0, abs=1e-6)
    assert norm(full["accel"]) == pytest.approx(1.0, abs=1e-6)  # gravity, at rest
    assert norm(full["mag"]) == pytest.approx(norm(EARTH_FIELD), abs=1e-6)
    # the rate is the body's turn about earth-down, seen in the sensor frame
    assert full["ang_rate"] == pytest.approx(rotate(m, (0, 0, Motion().yaw_rate)), abs=1e-6)
    euler = decode(sim.record(0xCE, t))
    assert (euler["roll"], euler["pitch"], euler["yaw"]) == pytest.approx(
        euler_from_matrix(m), abs=1e-6)
    # the update matrix carries the previous cycle's orientation into this one
    before = decode(sim.record(0xC5, t - period))["orientation"]
    update = decode(sim.record(0xC6, t))["orientation_update"]
    for got, want in zip(multiply(update, before), m, strict=True):
        assert got == pytest.approx(want, abs=1e-6)
    delta = decode(sim.record(0xC3, t))
    assert delta["delta_angle"] == pytest.approx(
        tuple(w * period for w in full["ang_rate"]), abs=1e-7)
    assert delta["delta_velocity"] == pytest.approx(
        tuple(a * period for a in full["accel"]), abs=1e-7)


def test_an_inertia_link_has_no_magnetometer():
    sim = node(model=INERTIA_LINK)
    for code in (0xC7, 0xCB, 0xCC, 0xD2, 0xD3):
        record = decode(sim.record(code, T0 + 1))
        mag = record["stab_mag" if code == 0xD2 else "mag"]
        assert all(math.isnan(v) for v in mag)


def test_continuous_mode_streams_one_record_per_cycle_at_the_divider_rate():
    sim = node(divider=1024)  # 50 Hz
    polled(sim, commands.set_continuous("euler"), at=T0 + 0.03)
    out = sim.run_until(T0 + 2.03)
    assert len(out) == 100
    timers = [decode(reply).timer for _, reply in out]
    assert {b - a for a, b in pairwise(timers)} == {1024 * 384}


def test_combined_mode_continuous_record_first_then_the_polled_reply():
    sim = node(stream="accel_angrate")
    sim.run_until(T0 + 0.1)
    for _ in range(3):
        sim.receive(commands.poll("euler").data)
    out = [decode(reply) for _, reply in sim.run_until(T0 + 0.1 + 4 * sim.period)]
    assert [r.name for r in out] == ["accel_angrate", "euler"] * 3 + ["accel_angrate"]


def test_stop_short_form_is_silent_long_form_is_answered():
    sim = node(stream="accel_angrate")
    sim.receive(commands.stop_continuous().data)
    assert sim.run_until(T0 + 1) == [] and sim.continuous == 0
    sim = node(stream="accel_angrate")
    sim.run_until(T0 + 0.5)
    replies = polled(sim, commands.stop_continuous_long(), at=T0 + 0.5 + 2 * sim.period)
    assert replies[-1].name == "continuous_mode" and replies[-1]["continuous_command"] == 0
    assert sim.run_until(T0 + 2) == []


def test_eeprom_divider_changes_the_rate_and_first_write_may_fail():
    sim = node()
    sim.first_write_failure_rate = 1.0
    failed = polled(sim, commands.set_divider(256))
    assert failed[0]["value"] == 512  # the reply shows the word unchanged
    retried = polled(sim, commands.set_divider(256), at=T0 + 2)
    assert retried[0]["value"] == 256 and sim.period == 256 / 51200
    assert polled(sim, commands.read_eeprom(0xFCA2), at=T0 + 3)[0]["value"] == 256


def test_power_up_auto_start_and_reset_state():
    sim = node()
    polled(sim, commands.set_auto_start("euler"))
    polled(sim, commands.write_accel_bias((0.5, 0.0, 0.0)), at=T0 + 2)
    assert sim.continuous == 0
    sim.power_up(T0 + 10)
    assert sim.continuous == 0xCE  # auto-start from EEPROM 0xFCA6
    assert sim.accel_bias == (0.0, 0.0, 0.0)  # RAM state is lost
    first = decode(sim.run_until(T0 + 10 + sim.period)[0][1])
    assert first.name == "euler" and first.timer == 512 * 384  # timer restarted


def test_bias_is_subtracted_and_capture_answers_after_sampling():
    sim = node()
    plain = decode(sim.record(0xC2, T0 + 1))["accel"]
    polled(sim, commands.write_accel_bias((0.25, 0.0, 0.0)))
    biased = decode(sim.record(0xC2, T0 + 1))["accel"]
    assert biased[0] == pytest.approx(plain[0] - 0.25, abs=1e-6)
    sim.receive(commands.capture_gyro_bias(500).data)
    assert sim.run_until(T0 + 1.4) == []
    replies = [decode(r) for _, r in sim.run_until(T0 + 1.6)]
    assert [r.name for r in replies] == ["capture_gyro_bias"]


def test_device_side_quirks_of_the_reference():
    sim = node()
    # 0xD0 with a quantity other than 1 or 2 stores nothing and answers 0xFFFF
    sim.receive(bytes.fromhex("D0 C1 29 00 07"))
    assert decode(sim.run_until(T0 + 1)[0][1])["quantity"] == 0xFFFF
    # wrong confirmation bytes: the node ignores the command
    sim.receive(bytes.fromhex("C4 C1 28 C2"))
    assert sim.run_until(T0 + 2) == [] and sim.log.ignored


def test_timer_wraps_at_two_to_the_32():
    sim = node(timer_start=218.4)
    ticks = [decode(sim.record(0xC2, T0 + dt)).timer for dt in (0.0, 0.1)]
    assert ticks[0] > ticks[1]  # wrapped in between
    assert (ticks[1] - ticks[0]) % TIMER_MODULUS == round(0.1 * TICKS_PER_SECOND)


# The simulator's replies as bytes, worked out by hand from the reference (record without
# its wired checksum), so the simulator, the table and the reference cannot drift together.
GOLDEN_REPLIES = [
    ("firmware 2.1.13", commands.firmware_version(), "E9 00 00 08 41"),  # 2113 = 0x0841
    ("divider word", commands.read_eeprom(0xFCA2), "E5 02 00"),          # 512
    ("eeprom write", commands.write_eeprom(0x0100, 0xBEEF), "E4 BE EF"),
    ("model name", commands.device_id(2),
     "EA 02" + " 49 6E 65 72 74 69 61 2D 4C 69 6E 6B" + " 20" * 4),   # "Inertia-Link"
    ("serial number", commands.device_id(1),
     "EA 01" + " 34 32 30 30 2D 30 30 37 36" + " 20" * 7),            # "4200-0076"
    ("built-in test", commands.built_in_test(0x14), "FB 14"),
    ("store gyro bias", commands.store_nonvolatile(2), "D0 00 02 00 00 00 00"),
]


@pytest.mark.parametrize(("command", "expected"), [g[1:] for g in GOLDEN_REPLIES],
                         ids=[g[0] for g in GOLDEN_REPLIES])
def test_simulator_replies_match_hand_made_bytes(command, expected):
    sim = node()
    sim.receive(command.data)
    ((_, reply),) = sim.run_until(T0 + sim.period)
    expected = bytes.fromhex(expected)
    if expected[0] == 0xD0:  # timed: the timer of the first cycle, 512 * 384 ticks
        expected = expected[:3] + (512 * 384).to_bytes(4, "big")
    assert reply == expected


def test_continuous_mode_confirmation_bytes():
    sim = node()
    sim.receive(bytes.fromhex("C4 C1 29 CE"))
    ((_, reply),) = sim.run_until(T0 + sim.period)
    assert reply == bytes.fromhex("C4 CE") + (512 * 384).to_bytes(4, "big")
    assert sim.continuous == 0xCE


def test_a_divider_change_long_after_power_up_keeps_the_stream_going():
    """Found through the gateway: cycles were counted from power-up at the current
    period, so a slower divider an hour in put the next cycle hours away (a minute in,
    minutes away: a minute shows it, at a sixtieth of the cycles to run)."""
    sim = node(stream="euler")
    sim.run_until(T0 + 60)
    polled(sim, commands.set_divider(2048), at=T0 + 60.02)
    out = sim.run_until(T0 + 61.02)
    assert 24 <= len(out) <= 26  # 25 Hz from the change on
    timers = [decode(reply).timer for _, reply in out]
    assert {b - a for a, b in pairwise(timers)} == {2048 * 384}


def test_a_crystal_off_by_some_ppm_runs_its_timer_and_its_cycles_that_much_fast() -> None:
    """Over 100 s of true time a +40 ppm node counts 100.004 s and makes its cycles
    that much more often; each record is still exactly one divider of ticks on."""
    fast = node(ppm=40.0, stream="euler")
    sent = fast.run_until(T0 + 100.0)
    timers = [decode(reply).timer for _, reply in sent]
    assert fast.timer_at(T0 + 100.0) == round(100.004 * TICKS_PER_SECOND)
    assert len(sent) == int(100.004 * 100)  # 100 Hz of its own clock
    assert {b - a for a, b in pairwise(timers)} <= {512 * 384 - 1, 512 * 384, 512 * 384 + 1}
    assert node().ppm == 0.0 and SimNode(NodeSettings(76), T0).ppm != \
        SimNode(NodeSettings(77), T0).ppm  # by default different for each node


def test_a_phase_starts_the_cycles_that_long_after_power_up_the_timer_at_it() -> None:
    """Nodes power up together; ``phase`` puts one's samples just after another's (the
    timer still counts from power-up), and a reboot keeps it."""
    first, later = node(stream="euler"), node(stream="euler", phase=0.004)
    times = [t for t, _ in first.run_until(T0 + 0.05)]
    shifted = [t for t, _ in later.run_until(T0 + 0.05)]
    assert [b - a for a, b in zip(times, shifted, strict=False)] == \
        pytest.approx([0.004] * len(shifted))
    assert later.timer_at(T0 + 1.0) == first.timer_at(T0 + 1.0)
    later.power_up(T0 + 10.0)
    assert later.next_cycle_time() == pytest.approx(T0 + 10.0 + 0.004 + 0.01)


def test_the_yaml_sets_a_nodes_crystal_phase_and_radio_jitter() -> None:
    from gateway.sim.config import SimConfig
    entry = SimConfig(nodes=[{"address": 77, "ppm": 80, "phase_ms": 4.5,
                              "radio": {"jitter_ms": 0}}]).nodes[0]
    assert (entry.build().ppm, entry.build().phase) == (80.0, 0.0045)
    assert entry.radio.build().jitter == 0.0
    plain = SimConfig(nodes=[{"address": 77}]).nodes[0]
    assert (plain.build().ppm, plain.build().phase, plain.radio.build().jitter) == \
        (None, 0.0, 0.0005)  # as before: ppm by address, no phase, 0.5 ms
