"""Samples missed while a base station was unplugged are its own kind of loss (issue
31: 2.8 s unplugged showed as hundreds lost over the radio): one station of a running
gx2-sim unplugged by name for 2 s, the other streaming on, through the installed
gx2-sim, gx2-gateway and gx2ctl."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tests.helpers.processes import STARTUP, Running, gx2ctl, script, spawn_run
from tests.helpers.waiting import wait_for

STATIONS = """\
base_stations:
  - name: north
    link: {tmp}/north
    nodes: [{{address: 76, stream: accel_angrate}}]
  - name: south
    link: {tmp}/south
    nodes: [{{address: 78, stream: accel_angrate}}]
"""
UNPLUGGED = 2.0
RATE = 100.0
"""Hz: the nodes' default divider."""


def test_an_unplugged_station_s_missed_samples_are_not_radio_loss(gateway, tmp_path: Path):
    config = tmp_path / "sim.yaml"
    config.write_text(STATIONS.format(tmp=tmp_path))
    sim = Running("gx2-sim", "--config", str(config))
    try:
        sim.wait_for_line(lambda line: line.startswith("south: "), STARTUP)
        gw = gateway(None, [], base_stations=[
            {"name": name, "port": str(tmp_path / name),
             "nodes": [{"address": address}]} for name, address in (("north", 76),
                                                                    ("south", 78))])
        gw.wait_streaming(76, 78)
        sub = gw.subscribe("gx2/76/accel_angrate")
        sub.until(lambda m: len(m) >= 50, 10, "north's records")
        unplug = spawn_run([script("gx2-sim"), "unplug", "north", "--seconds",
                            f"{UNPLUGGED:g}", "--pid", str(sim.proc.pid)],
                           capture_output=True, text=True, timeout=30,
                           stdin=subprocess.DEVNULL)
        assert unplug.returncode == 0, unplug
        wait_for(lambda: gw.status()["stations"][0]["state"] != "up", 5, "north down")
        wait_for(lambda: gw.status()["stations"][0]["state"] == "up", 15, "north back")
        gw.wait_streaming(76)
        before = len(sub.messages)
        sub.until(lambda m: len(m) >= before + 50, 10, "north's records again")

        steps = [b["device_time"] - a["device_time"]
                 for (_, a), (_, b) in zip(sub.messages, sub.messages[1:], strict=False)]
        gap = round(max(steps) * RATE) - 1  # the samples the outage took, by the timer
        assert gap >= UNPLUGGED * RATE * 0.9, gap
        ran = gx2ctl("--config", str(gw.path), "--json", "status")
        assert ran.status == 0, ran
        nodes = {n["node"]: n for n in json.loads(ran.stdout)["nodes"]}
        north, south = nodes[76], nodes[78]
        assert north["lost_radio"] <= 2, north  # (the simulated radio loses nothing)
        assert abs(north["lost_station_down"] - gap) <= 2, (north, gap)
        assert south["lost_station_down"] == 0 and south["lost_radio"] <= 2, south
    finally:
        sim.kill()
