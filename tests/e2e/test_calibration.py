"""Bias capture, bias corrections, storing them, temperatures and the built-in test,
through gx2ctl, the real gateway and gx2-sim on a pty: what reaches the node, what
gx2ctl prints and its exit status, and the refusals when writes are not allowed."""

from __future__ import annotations

import math
import re
import time

import msgpack
import pytest

from aspp.temperature import accel_celsius, gyro_celsius
from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.helpers.processes import Running, gx2ctl
from tests.helpers.simulated import continuous, received
from tests.helpers.waiting import wait_for

STILL = Motion(yaw_rate=0.0)
BIAS_ERROR = (0.002, -0.001, 0.0015)
NOISY = {"accel_noise": 0.002, "rate_noise": 0.004}


def node_state(sim, node: int, name: str):
    return sim.call(lambda station, now: getattr(station.nodes[node], name))


def test_bias_capture_stops_the_stream_captures_once_and_restores_it(simulator, gateway):
    sim = simulator(NodeSettings(76, motion=STILL, gyro_bias_error=BIAS_ERROR))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    start = time.monotonic()
    ran = gx2ctl("--config", str(gw.path), "--timeout", "3", "bias", "capture", "76",
                 "--ms", "1500")
    took = time.monotonic() - start
    assert ran.status == 0, ran
    assert "keep it still" in ran.stderr
    assert took >= 1.5
    numbers = [float(x) for x in re.findall(r"[xyz] ([+-]\d+\.\d+)", ran.stdout)]
    assert numbers == pytest.approx(BIAS_ERROR, abs=1e-5), ran.stdout
    assert "streamed accel_angrate: stopped for the capture, accel_angrate started again" \
        in ran.stdout
    captures = received(sim, 76, 0xCD)
    assert [c.arguments["sampling_time"] for c in captures] == [1500]  # never sent twice
    assert continuous(sim, 76) == 0xC2
    sub = gw.subscribe("gx2/76/accel_angrate")
    since = time.time()
    records = sub.until(lambda m: sum(p["host_time"] > since for _, p in m) >= 5, 5,
                        "records after the capture")
    rates = [p["ang_rate"] for _, p in records if p["host_time"] > since]
    assert all(abs(v) < 1e-5 for rate in rates for v in rate), rates  # corrected


@pytest.mark.parametrize("command", [["bias", "set", "76", "gyro", "0.001", "0", "0"],
                                     ["store", "76", "accel"]])
def test_bias_changes_are_refused_unless_writes_are_allowed(simulator, gateway, command):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}])
    ran = gx2ctl("--config", str(gw.path), *command)
    assert ran.status == 1 and "allow_eeprom_write" in ran.stderr, ran
    assert received(sim, 76, 0xCA) == received(sim, 76, 0xD0) == []


def test_a_bias_set_and_stored_outlives_a_reboot(simulator, gateway):
    sim = simulator(NodeSettings(76, motion=STILL))
    gw = gateway(sim.path, [{"address": 76}], control={"allow_eeprom_write": True})
    ran = gx2ctl("--config", str(gw.path), "bias", "set", "76", "accel", "0.01", "-0.02",
                 "0.03")
    assert ran.status == 0, ran
    assert "accel bias correction set (echoed): x +0.010000  y -0.020000  z +0.030000 g" \
        in ran.stdout
    sent = received(sim, 76, 0xC9)
    assert len(sent) == 1 and sent[0].data[1:3] == b"\xB7\x44"  # the confirmation bytes
    ran = gx2ctl("--config", str(gw.path), "store", "76", "accel")
    assert ran.status == 0 and "accel bias stored" in ran.stdout, ran
    assert [c.arguments["quantity"] for c in received(sim, 76, 0xD0)] == [1]
    sim.reboot(76)
    wait_for(lambda: gw.node_status(76)["reboots"] == 1, 10, "the reboot")
    polled = gw.control.result("poll", node=76, record="accel_angrate")
    gravity = STILL.accel(0.0)
    assert polled["accel"] == pytest.approx([g - b for g, b in zip(
        gravity, (0.01, -0.02, 0.03), strict=True)], abs=1e-6)


def test_temperature_in_degrees_for_the_configured_gyro(simulator, gateway):
    sim = simulator(NodeSettings(76, gyro="ADXRS300"))
    gw = gateway(sim.path, [{"address": 76, "gyro": "ADXRS300"}])
    ran = gx2ctl("--config", str(gw.path), "temperature", "76")
    assert ran.status == 0, ran
    rows = dict(re.findall(r"^(accel|gyro [xyz]) +(-?\d+\.\d+) +\d+$", ran.stdout, re.M))
    assert set(rows) == {"accel", "gyro x", "gyro y", "gyro z"}, ran.stdout
    assert all(20 < float(v) < 35 for v in rows.values()), rows
    assert "ADXRS300" in ran.stdout
    result = gw.control.result("temperature", node=76)
    assert result["accel_c"] == pytest.approx(accel_celsius(result["codes"][0]), abs=0.01)
    assert result["gyro_c"][0] == pytest.approx(gyro_celsius(result["codes"][1], "ADXRS300"),
                                                abs=0.01)


def test_a_healthy_node_passes_its_self_test_and_bit_ends_off(simulator, gateway):
    sim = simulator(NodeSettings(76, motion=STILL, **NOISY))
    gw = gateway(sim.path, [{"address": 76, "stream": "euler"}])
    gw.wait_streaming(76)
    ran = gx2ctl("--config", str(gw.path), "selftest", "76")
    assert ran.status == 0, ran
    lines = [line for line in ran.stdout.splitlines() if line.endswith(("pass", "FAIL"))]
    assert len(lines) == 20 and all(line.endswith("pass") for line in lines), ran.stdout
    assert "76 self-test passed (20 checks)" in ran.stdout
    assert [c.arguments["test_config"] for c in received(sim, 76, 0xFB)] == [0x10, 0x20, 0x00]
    assert node_state(sim, 76, "test_config") == 0
    assert continuous(sim, 76) == 0xCE, "the stream was not started again"


def test_a_sensor_that_does_not_step_fails_the_self_test(simulator, gateway):
    sim = simulator(NodeSettings(77, motion=STILL, bit_faults=frozenset({"rate_y"}), **NOISY))
    gw = gateway(sim.path, [{"address": 77}])
    ran = gx2ctl("--config", str(gw.path), "selftest", "77")
    assert ran.status == 1, ran
    failed = [line.split("  ")[0] for line in ran.stdout.splitlines() if line.endswith("FAIL")]
    assert failed == ["bit4 rate y steps up", "bit5 rate y steps down"], ran.stdout
    assert "failed its self-test: bit4 rate y steps up, bit5 rate y steps down" in ran.stderr
    assert node_state(sim, 77, "test_config") == 0


def test_bit_is_switched_off_when_the_self_test_is_cut_short(simulator, gateway):
    """The request's own deadline ends the test while BIT is on: the answer is a node
    error, and BIT is off all the same."""
    # at 10 Hz each phase of 11 polls takes about 1.1 s: BIT goes on at about 1.2 s and
    # the deadline (answered 0.18 s before 1.8 s) falls while it is on
    sim = simulator(NodeSettings(76, motion=STILL, divider=5120))
    gw = gateway(sim.path, [{"address": 76}])
    gw.control.send_raw(b"", msgpack.packb({"id": "cut", "op": "selftest", "node": 76,
                                            "timeout": 1.8}))
    reply = gw.control.receive(10)
    assert reply is not None and reply["ok"] is False and reply["error"]["kind"] == "node"
    configs = [c.arguments["test_config"] for c in received(sim, 76, 0xFB)]
    assert configs[:1] == [0x10], "the test was not cut short while BIT was on"
    wait_for(lambda: node_state(sim, 76, "test_config") == 0, 5, "BIT to be off")
    assert received(sim, 76, 0xFB)[-1].arguments["test_config"] == 0


def test_info_shows_the_firmware_as_a_version(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}])
    ran = gx2ctl("--config", str(gw.path), "info", "76")
    assert ran.status == 0 and re.search(r"^firmware +2113 \(2\.1\.13\)$", ran.stdout, re.M)
    assert math.isfinite(gw.control.result("temperature", node=76)["accel_c"])


def test_a_capture_cut_short_by_an_unplug_leaves_the_node_link_down(simulator, gateway):
    """The base station goes during a bias capture: the capture fails, and the node is
    shown as what it is (link down, ERROR), not as polled and OK; once the base station
    is back its stream is armed again like any other node's."""
    sim = simulator(NodeSettings(76, motion=STILL), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}])
    gw.wait_streaming(76, 77)
    capture = Running("gx2ctl", "--config", str(gw.path), "bias", "capture", "76",
                      "--ms", "3000")
    try:
        wait_for(lambda: received(sim, 76, 0xCD), 5, "the capture to reach node 76")
        sim.unplug()
        assert capture.finish(10) == 1, capture.stderr
    finally:
        capture.kill()
    status = gw.status()
    assert status["link"]["state"] == "down"
    nodes = {n["node"]: n for n in status["nodes"]}
    for address in (76, 77):
        assert (nodes[address]["state"], nodes[address]["health"]) == ("link down", "ERROR"), \
            nodes[address]
    sim.replug()
    gw.wait_streaming(76, 77, timeout=10)
    sub = gw.subscribe("gx2/76/accel_angrate")
    sub.until(lambda m: len(m) >= 5, 5, "node 76 streaming again")
