"""Rough edges a new user hit, each through the installed scripts: tail and a slow
heartbeat, tail of a node the gateway does not have, a port that cannot work, a record
given as a number in YAML, and the warning of a node that cannot be armed."""

from __future__ import annotations

import re
import signal
import time
from pathlib import Path

from gateway.sim.node import NodeSettings
from tests.helpers.processes import Running, gx2ctl, script, spawn_run
from tests.helpers.simulated import continuous
from tests.helpers.waiting import wait_for

START = 30.0


def test_tail_waits_out_a_heartbeat_slower_than_its_timeout(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}], publish={"heartbeat_s": 3.0})
    tail = Running("gx2ctl", "--config", str(gw.path), "--timeout", "1", "tail")
    try:
        time.sleep(2.5)  # the window in which it must not give up: the test itself
        assert tail.proc.poll() is None, f"tail gave up: {tail.stderr}"
        tail.proc.send_signal(signal.SIGINT)
        assert tail.finish(START) == 0 and tail.stderr == []
    finally:
        tail.kill()


def test_tail_of_a_node_the_gateway_does_not_have_is_a_usage_error(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}])
    for where in (["--config", str(gw.path)], ["--control", gw.control_endpoint]):
        ran = gx2ctl(*where, "--timeout", "5", "tail", "76", "100", timeout=30)
        assert ran.status == 2 and "node 100 is not configured" in ran.stderr, ran


def test_a_port_that_cannot_work_says_why(tmp_path: Path, gateway):
    port = tmp_path / "not-a-port"
    port.write_text("")
    gw = gateway(str(port), [{"address": 76}], wait=False)
    # (between two attempts to open it the link is "down", during one "opening": a
    # loaded machine once caught the second)
    wait_for(lambda: (r := gw.control.try_call("status", 0.5)) and r["ok"]
             and r["result"]["link"]["error"] and r["result"]["link"]["state"] == "down",
             START, "status to say why the link is down")
    link = gw.status()["link"]
    assert "ioctl" in link["error"].lower(), link
    ran = gx2ctl("--config", str(gw.path), "status")
    assert re.search(r"^link .* (down|opening) for .*\(.*ioctl.*\)", ran.stdout,
                     re.M | re.I), ran.stdout
    time.sleep(2.5)  # several retries (every second): the reason is logged once
    assert gw.log().count("cannot be opened") == 1, gw.log()
    check = spawn_run([script("gx2-gateway"), "--config", str(gw.path), "--check"],
                      capture_output=True, text=True, timeout=START)
    assert check.returncode == 2 and "is a regular file, not a serial port" in check.stderr


def test_a_record_given_as_a_number_in_yaml(simulator, tmp_path: Path, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76, "stream": 0xCE}])  # YAML: stream: 206
    gw.wait_streaming(76)
    assert gw.node_status(76)["record"] == "euler" and continuous(sim, 76) == 0xCE


def test_a_node_that_cannot_be_armed_is_said_to_be_read_for_its_rate(gateway):
    gw = gateway("sim://?out_of_range=95", [{"address": 95, "stream": "euler"}])
    wait_for(lambda: "retrying in" in gw.log(), START, "a retry")
    line = next(line for line in gw.log().splitlines() if "retrying in" in line)
    assert "reading its data-rate divider (EEPROM 0xFCA2)" in line, line
    assert "(4 attempts)" in line
