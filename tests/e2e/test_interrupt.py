"""Ctrl-C in gx2ctl during a long operation (issue 31, defect 11), through the installed
gx2ctl and gateway and gx2-sim on a pty: the gateway cancels the request where it
safely can (the node left as it was) or says that it goes on; gx2ctl says which in one
line and exits 130; the gateway logs it either way."""

from __future__ import annotations

import re
import signal

import pytest

from aspp.host_side import CommandPacket
from aspp.selftest import POSITIVE_BIT
from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.helpers.processes import Running
from tests.helpers.simulated import continuous, received, station_stat
from tests.helpers.waiting import wait_for

STILL = Motion(yaw_rate=0.0)
BIAS_ERROR = (0.002, -0.001, 0.0015)
INTERRUPTED = 130


def interrupt(ctl: Running) -> list[str]:
    """Ctrl-C to gx2ctl; what it said on stderr, once it has exited 130 (promptly)."""
    ctl.proc.send_signal(signal.SIGINT)
    assert ctl.finish(5) == INTERRUPTED, ctl.stderr
    return [line.rstrip("\n") for line in ctl.stderr]


def deaf(sim, node: int, deaf: bool) -> None:
    """Every command to ``node`` lost over the radio (or none)."""
    def change(station, now) -> None:
        station.radio[node].command_loss = 1.0 if deaf else 0.0
    sim.call(change)


def captures_sent(sim, node: int) -> list[CommandPacket]:
    """The 0xCD packets for ``node`` that the base station took from the gateway."""
    return sim.call(lambda station, now: [
        event for _, event in station.from_host_log
        if isinstance(event, CommandPacket) and event.node == node
        and event.command[:1] == b"\xcd"])


def test_ctrl_c_before_the_capture_went_out_cancels_it_and_the_bias_stays(simulator,
                                                                          gateway):
    sim = simulator(NodeSettings(76, motion=STILL, gyro_bias_error=BIAS_ERROR),
                    radio={76: RadioLink()})
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    deaf(sim, 76, True)  # the stop before the capture goes on being retried
    lost = station_stat(sim, "commands_lost")
    ctl = Running("gx2ctl", "--config", str(gw.path), "bias", "capture", "76", "--ms", "1000")
    try:
        wait_for(lambda: station_stat(sim, "commands_lost") > lost, 10,
                 "the stop before the capture to go out")
        said = interrupt(ctl)
    finally:
        ctl.kill()
    cancelled = "bias capture on 76 cancelled by the client; bias unchanged"
    assert said == ["gx2ctl: node 76 samples its sensors for 1000 ms: keep it still until then",
                    f"gx2ctl: interrupted: {cancelled}"], said
    wait_for(lambda: cancelled in gw.log(), 5, "the gateway to log the cancel")
    deaf(sim, 76, False)
    wait_for(lambda: gw.node_status(76)["state"] == "streaming", 10, "76 streaming again")
    assert captures_sent(sim, 76) == []  # nothing of the capture ever went out
    assert sim.call(lambda station, now: station.nodes[76].gyro_bias) == (0.0, 0.0, 0.0)


def test_ctrl_c_while_the_node_samples_says_the_capture_goes_on_and_logs_its_end(simulator,
                                                                                gateway):
    sim = simulator(NodeSettings(76, motion=STILL, gyro_bias_error=BIAS_ERROR))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    ctl = Running("gx2ctl", "--config", str(gw.path), "bias", "capture", "76", "--ms", "2000")
    try:
        wait_for(lambda: received(sim, 76, 0xCD), 10, "the capture to reach the node")
        said = interrupt(ctl)
    finally:
        ctl.kill()
    assert len(said) == 2 and re.fullmatch(
        r"gx2ctl: interrupted: bias capture on 76 goes on: the node is already sampling "
        r"\(a capture cannot be stopped\) and takes its new gyro bias in [12]\.\d s; the "
        r"gateway logs it", said[1]), said
    assert "bias capture on 76 goes on" in gw.log()
    wait_for(lambda: "node 76: gyro bias captured over 2 s: x +0.002000 y -0.001000 "
             "z +0.001500 rad/s; accel_angrate started again" in gw.log(), 5,
             "the gateway to log the capture's end")
    assert len(received(sim, 76, 0xCD)) == 1
    assert continuous(sim, 76) == 0xC2  # its stream started again after the capture
    bias = sim.call(lambda station, now: station.nodes[76].gyro_bias)
    assert bias == pytest.approx(BIAS_ERROR, abs=1e-6)


def test_ctrl_c_during_a_self_test_cancels_it_with_bit_off_and_the_stream_back(simulator,
                                                                               gateway):
    sim = simulator(NodeSettings(76, motion=STILL))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    ctl = Running("gx2ctl", "--config", str(gw.path), "selftest", "76")
    try:
        wait_for(lambda: any(c.arguments["test_config"] == POSITIVE_BIT
                             for c in received(sim, 76, 0xFB)), 10, "BIT on")
        said = interrupt(ctl)
    finally:
        ctl.kill()
    cancelled = ("selftest on 76 cancelled by the client; BIT switched off (the gateway "
                 "keeps at it until the node confirms) and any stream it ran started again")
    assert said[1:] == [f"gx2ctl: interrupted: {cancelled}"], said
    assert cancelled in gw.log()
    assert sim.call(lambda station, now: station.nodes[76].test_config) == 0
    wait_for(lambda: continuous(sim, 76) == 0xC2, 5, "the stream started again")
