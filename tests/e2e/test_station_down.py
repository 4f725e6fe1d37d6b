"""Samples missed while a base station was unplugged are its own kind of loss (issue
31: 2.8 s unplugged showed as hundreds lost over the radio): one station of a running
gx2-sim unplugged by name for 2 s, the other streaming on, through the installed
gx2-sim, gx2-gateway and gx2ctl."""

from __future__ import annotations

import json
import re
import signal
import subprocess
from pathlib import Path

from gateway.recording.plot import picture, records_of
from gateway.recording.reports import Reading
from tests.helpers.gateway import RunningGateway, Subscriber
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
        unplug_north_while_streaming(sim, gw, sub)

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


LINE = re.compile(r"radio: ([\d,]+) lost \([\d.]+%\)[,·\s]+gateway: ([\d,]+) lost "
                  r"\([\d.]+%\)[,·\s]+station down: ([\d,]+) lost")


def said(text: str) -> tuple[int, int, int]:
    """(radio, gateway, station down) as a summary line says them."""
    found = LINE.search(text)
    assert found, text
    radio, gateway_lost, down = (int(group.replace(",", "")) for group in found.groups())
    return radio, gateway_lost, down


def test_the_summaries_of_a_recording_say_an_unplug_apart_from_radio_loss(
        gateway, tmp_path: Path):
    """gx2ctl record's summary, export's per-table lines and the plot's title, from the
    status messages recorded beside the records (the station's state and since)."""
    config = tmp_path / "sim.yaml"
    config.write_text(STATIONS.format(tmp=tmp_path))
    sim = Running("gx2-sim", "--config", str(config))
    record = None
    try:
        sim.wait_for_line(lambda line: line.startswith("south: "), STARTUP)
        directory = tmp_path / "recordings"
        gw = gateway(None, [], base_stations=[
            {"name": name, "port": str(tmp_path / name),
             "nodes": [{"address": address}]} for name, address in (("north", 76),
                                                                    ("south", 78))],
            record={"directory": str(directory)})
        gw.wait_streaming(76, 78)
        capture = tmp_path / "capture.mcap"
        record = Running("gx2ctl", "--control", gw.control_endpoint, "record", str(capture))
        sub = gw.subscribe("gx2/76/accel_angrate")
        unplug_north_while_streaming(sim, gw, sub)
        record.proc.send_signal(signal.SIGINT)
        assert record.finish(10) == 0, record.stderr
        status, _ = gw.terminate()
        assert status == 0
        steps = [b["device_time"] - a["device_time"]
                 for (_, a), (_, b) in zip(sub.messages, sub.messages[1:], strict=False)]
        gap = round(max(steps) * RATE) - 1
        # (twice, in full runs on a loaded machine, no gap at all: said in full if again)
        assert gap >= UNPLUGGED * RATE * 0.9, (gap, outage_said(sub, steps), gw.log()[-3000:])

        # gx2ctl record's summary: both stations' streams, one of them unplugged
        radio, gw_gap, down = said("".join(record.stderr))
        assert radio <= 4 and gw_gap == 0, record.stderr
        assert abs(down - gap) <= 3, (record.stderr, gap)

        # export, of the gateway's recording and of gx2ctl record's file
        for source in (directory, capture):
            out = tmp_path / f"out-{source.stem}"
            ran = gx2ctl("export", str(source), "--out", str(out))
            assert ran.status == 0, ran.stderr
            lines = {Path(line.split()[0]).name: line for line in ran.stdout.splitlines()}
            north = re.search(r"station down: ([\d,]+) lost", lines["76_accel_angrate.csv"])
            assert north and abs(int(north[1]) - gap) <= 3, (ran.stdout, gap)
            assert "station down" not in lines["78_accel_angrate.csv"], ran.stdout

            # the plot's title
            found = records_of([source] if source.is_file() else
                               sorted(source.glob("*.mcap")), 76, None, Reading())
            image = picture(76, found.record, found.payloads, found.name, found.marks,
                            found.counts)
            radio, _, down = said(image.title)
            assert radio <= 2 and abs(down - gap) <= 3, (image.title, gap)
            found = records_of([source] if source.is_file() else
                               sorted(source.glob("*.mcap")), 78, None, Reading())
            image = picture(78, found.record, found.payloads, found.name, found.marks,
                            found.counts)
            assert "station down" not in image.title, image.title
    finally:
        if record is not None:
            record.kill()
        sim.kill()


def outage_said(sub: Subscriber, steps: list[float]) -> str:
    """What the records say of the outage: their device time's largest and smallest
    steps, the largest step of their host time, and each record's seq and timer."""
    hosts = [b["host_time"] - a["host_time"]
             for (_, a), (_, b) in zip(sub.messages, sub.messages[1:], strict=False)]
    return (f"{len(sub.messages)} records; device steps {max(steps):.3f} / {min(steps):.3f} s,"
            f" host steps up to {max(hosts):.3f} s; (seq, timer): "
            f"{[(p['seq'], p['timer']) for _, p in sub.messages]}")


def unplug_north_while_streaming(sim: Running, gw: RunningGateway, sub: Subscriber) -> None:
    """Station north unplugged for UNPLUGGED seconds with ``gx2-sim unplug``, between
    50 of node 76's records before and 50 after it is back."""
    sub.until(lambda m: len(m) >= 50, 10, "north's records")
    unplug = spawn_run([script("gx2-sim"), "unplug", "north", "--seconds",
                        f"{UNPLUGGED:g}", "--pid", str(sim.proc.pid)],
                       capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    assert unplug.returncode == 0, unplug
    wait_for(lambda: gw.status()["stations"][0]["state"] != "up", 5, "north down")
    wait_for(lambda: gw.status()["stations"][0]["state"] == "up", 15, "north back")
    gw.wait_streaming(76)
    before = len(sub.messages)
    sub.until(lambda m: len(m) >= before + 50, 10, "north's records again")
