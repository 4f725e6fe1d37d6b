"""Nodes heard that the gateway is not configured for (issue 35, parts 1 and 4), through
the installed programs: gx2-sim with nodes of its own beside the gateway's one, some
streaming, some silent, some switched off and on with ``gx2-sim power``; the installed
gateway lists exactly those it heard under their station (``gx2ctl status``, ``--json``,
the metrics) and WARNs while one streams on its channel."""

from __future__ import annotations

import re
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.sim.node import NodeSettings
from tests.e2e.test_watching import Scraper
from tests.helpers.ports import free_port
from tests.helpers.processes import STARTUP, Running, gx2ctl, script, spawn_run
from tests.helpers.waiting import wait_for

SIM = """\
nodes:
  - {address: 76, stream: accel_angrate}               # the gateway's one node
  - {address: 81, stream: accel_angrate, divider: 1024, radio: {rssi: -61}}  # 50 Hz
  - {address: 82, stream: euler, divider: 2048}        # 25 Hz
  - {address: 83, powered: false}                      # switched on: a discovery alone
  - {address: 84, stream: accel_angrate, divider: 5120, powered: false}  # on: 10 Hz
  - {address: 85}                                      # on, silent: never heard
  - {address: 86, stream: euler, powered: false}       # off throughout: never heard
"""


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[tuple[Running, Path]]:
    """The installed gx2-sim running SIM, once it serves on its link."""
    config, link = tmp_path / "sim.yaml", tmp_path / "gx2"
    config.write_text(SIM)
    running = Running("gx2-sim", "--config", str(config), "--link", str(link))
    try:
        running.wait_for_line(lambda line: line == str(link), STARTUP)
        yield running, link
    finally:
        running.kill()


def sim_command(*args: str) -> subprocess.CompletedProcess:
    return spawn_run([script("gx2-sim"), *args], capture_output=True, text=True,
                     timeout=30, stdin=subprocess.DEVNULL)


def heard(status: dict[str, Any]) -> dict[int, dict[str, Any]]:
    (station,) = status["stations"]
    return {entry["address"]: entry for entry in station["heard"]}


def test_status_lists_exactly_the_nodes_heard_that_are_not_configured(
        sim: tuple[Running, Path], gateway) -> None:
    running, link = sim
    metrics = f"127.0.0.1:{free_port()}"
    gw = gateway(str(link), [{"address": 76, "stream": "accel_angrate"}],
                 metrics={"endpoint": metrics})
    gw.wait_streaming(76)
    # the two streaming from the start, with their records and their timers' rates
    wait_for(lambda: {a: h["rate_hz"] for a, h in heard(gw.status()).items()}
             == {81: 50.0, 82: 25.0}, 10, "81 and 82 heard streaming")
    # (76 is not blamed for them: OK once its clock has locked, a second or two in, WARN
    # 'clock not locked' until then)
    wait_for(lambda: gw.node_status(76)["health"] == "OK", 10, "node 76 OK")
    status = gw.status()
    assert heard(status)[81]["record"] == "accel_angrate"
    assert heard(status)[82]["record"] == "euler"
    assert -64 <= heard(status)[81]["rssi"] <= -59 and heard(status)[81]["packets"] > 2
    assert abs(heard(status)[81]["last_heard"] - status["gateway"]["time"]) < 1
    assert "heard" not in status["link"]  # (the station's, not its link's)
    # each takes radio time from the configured one: the station and the gateway WARN
    reasons = ["node 81 (not configured) streams accel_angrate at 50 Hz on its channel",
               "node 82 (not configured) streams euler at 25 Hz on its channel"]
    assert status["stations"][0]["reasons"] == reasons
    assert status["gateway"]["health"] == "WARN"
    assert set(reasons) <= set(status["gateway"]["reasons"])
    # (not by them: OK once its clock locked, its line's first second said unlocked)
    wait_for(lambda: next(n for n in gw.status()["nodes"] if n["node"] == 76)["health"]
             == "OK", 10, "node 76 OK")

    shown = gx2ctl("--config", str(gw.path), "status")
    assert shown.status == 0, shown
    lines = shown.stdout.splitlines()
    assert re.fullmatch(r" +heard, not configured: 81 streaming accel_angrate at 50 Hz, "
                        r"RSSI -6\d, last \d\.\d s ago", lines[lines.index(next(
                            line for line in lines if line.startswith("link"))) + 1]), lines
    assert any(line.strip().startswith("heard, not configured: 82 streaming euler at 25 Hz")
               for line in lines), lines
    check = gx2ctl("--config", str(gw.path), "status", "--check")
    assert check.status == 1 and "node 81 (not configured) streams" in check.stderr, check
    scrape = Scraper(metrics)
    wait_for(lambda: scrape.value("gx2_station_heard_nodes", station="station1") == 2.0, 5,
             "gx2_station_heard_nodes to count them")
    assert scrape.value("gx2_station_heard_streaming_nodes", station="station1") == 2.0

    # nodes added mid-study: 83 powers up announcing itself and stays silent, 84 powers
    # up and streams what it auto-starts
    for address in ("83", "84"):
        done = sim_command("power", address, "on", "--pid", str(running.proc.pid))
        assert done.returncode == 0, done
        assert done.stdout.strip() == f"node {address} switched on: it powers up", done
    wait_for(lambda: set(heard(gw.status())) == {81, 82, 83, 84}
             and heard(gw.status())[84]["rate_hz"] == 10.0, 10, "83 and 84 heard")
    entries = heard(gw.status())
    assert entries[83]["record"] is None and entries[83]["rate_hz"] is None
    assert entries[83]["packets"] == 1 and entries[83]["announced"] is not None
    assert entries[84]["record"] == "accel_angrate" and entries[84]["announced"] is not None
    shown = gx2ctl("--config", str(gw.path), "status").stdout
    assert "heard, not configured: 83 powered up (a discovery packet), RSSI -4" in shown

    # 81 switched off: still remembered, no longer streaming, no longer a reason
    done = sim_command("power", "81", "off", "--pid", str(running.proc.pid))
    assert done.returncode == 0 and done.stdout.strip() == "node 81 switched off", done
    wait_for(lambda: heard(gw.status())[81]["rate_hz"] is None, 5, "81 to stop streaming")
    status = gw.status()
    assert set(heard(status)) == {81, 82, 83, 84}  # 85 and 86 never sent a thing
    assert status["stations"][0]["reasons"] == [
        reasons[1], "node 84 (not configured) streams accel_angrate at 10 Hz on its channel"]
    wait_for(lambda: scrape.value("gx2_station_heard_streaming_nodes",
                                  station="station1") == 2.0
             and scrape.value("gx2_station_heard_nodes", station="station1") == 4.0, 5,
             "the metrics to follow")
    assert "node 81, not configured, streams accel_angrate on its channel" in gw.log()
    assert gw.node_status(76)["lost_radio"] == 0


def test_gx2_sim_power_says_in_one_line_what_it_cannot_do(sim: tuple[Running, Path]) -> None:
    running, _ = sim
    pid = str(running.proc.pid)
    done = sim_command("power", "99", "on", "--pid", pid)
    assert done.returncode == 1, done
    assert done.stderr.strip() == "gx2-sim: no running gx2-sim has a node 99", done
    done = sim_command("power", "84", "off", "--pid", pid)
    assert done.returncode == 0 and done.stdout.strip() == "node 84 was off already", done
    for bad in (["84", "maybe"], ["0", "on"], ["84"]):
        done = sim_command("power", *bad, "--pid", pid)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done


def test_sim_url_extra_nodes_are_heard_and_a_configured_one_is_refused(gateway,
                                                                      tmp_path) -> None:
    """``sim://?extra=81:accel_angrate,82``: the embedded simulator's nodes that the
    gateway is not configured for (82 streams nothing: never heard)."""
    gw = gateway("sim://?extra=81:accel_angrate,82", [{"address": 76,
                                                       "stream": "accel_angrate"}])
    wait_for(lambda: {a: (h["record"], h["rate_hz"]) for a, h in heard(gw.status()).items()}
             == {81: ("accel_angrate", 100.0)}, 10, "81 heard streaming at 100 Hz")
    config = tmp_path / "bad.yaml"
    config.write_text(gw.path.read_text().replace("extra=81:accel_angrate,82", "extra=76"))
    checked = spawn_run([script("gx2-gateway"), "--config", str(config), "--check"],
                        capture_output=True, text=True, timeout=60)
    assert checked.returncode == 2, checked
    assert "sim:// extra names node 76, which is configured" in checked.stderr, checked
    assert len(checked.stderr.strip().splitlines()) == 1, checked


def test_a_node_heard_and_then_added_by_a_reload_is_heard_no_longer(simulator,
                                                                    gateway) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(81, stream="accel_angrate"))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    wait_for(lambda: heard(gw.status()).get(81, {}).get("rate_hz") == 100.0, 10,
             "81 heard streaming")
    gw.path.write_text(yaml.safe_dump({**gw.config, "nodes": [
        {"address": 76, "stream": "accel_angrate"}, {"address": 81}]}))
    gw.proc.send_signal(signal.SIGHUP)
    wait_for(lambda: 81 in {n["node"] for n in gw.status()["nodes"]}, 10, "81 added")
    status = gw.status()
    assert heard(status) == {} and status["stations"][0]["reasons"] == []
    gw.wait_streaming(81)  # (what it streams by itself, taken as it is)
    assert heard(gw.status()) == {}
