"""Several base stations in one gateway (issue 22), through real ptys: two gx2-sim base
stations, each with its own nodes, one gateway publishing, commanding, recording and
replaying both; one unplugged while the other streams."""

from __future__ import annotations

import contextlib
import json
import math
import statistics
import subprocess
import time
from itertools import pairwise
from pathlib import Path

import pytest

from aspp.decoder import Decoder
from aspp.events import Reply
from gateway.common.jsontext import strict
from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from tests.e2e.test_recording import payloads, recorded
from tests.e2e.test_sample_time import errors
from tests.helpers.processes import gx2ctl, script
from tests.helpers.waiting import wait_for

DIVIDER = 512
"""100 Hz."""
LATENCY_MS = RADIO_LATENCY * 1000


def written_at(sim) -> dict[int, float]:
    """When (UNIX seconds) the simulator wrote each record into its pty, by its timer."""
    decoder, written, write = Decoder(), {}, sim.port.write

    def tapped(data: bytes) -> int:
        count = write(data)
        now = time.time()
        for event in decoder.feed(data[:count]):
            if type(event) is Reply and len(event.payload) >= 4:
                written[int.from_bytes(event.payload[-4:], "big")] = now
        return count
    sim.port.write = tapped
    return written


def two_stations(simulator, gateway, **sections):
    north = simulator(NodeSettings(76, divider=DIVIDER, stream="accel_angrate", ppm=25.0),
                      NodeSettings(77, divider=DIVIDER, stream="euler"), name="north")
    south = simulator(NodeSettings(78, divider=DIVIDER, stream="accel_angrate", ppm=-30.0),
                      name="south")
    gw = gateway(None, [], base_stations=[
        {"name": "north", "port": north.path, "latency_ms": LATENCY_MS,
         "nodes": [{"address": 76}, {"address": 77}]},
        {"name": "south", "port": south.path, "latency_ms": LATENCY_MS,
         "nodes": [{"address": 78}]}], **sections)
    gw.wait_streaming(76, 77, 78)
    return north, south, gw


@pytest.mark.usefixtures("favoured_host")
def test_each_station_shows_everywhere_and_one_unplugged_never_delays_another(
        simulator, gateway):
    north, south, gw = two_stations(simulator, gateway)
    written = written_at(south)
    status = gw.status()
    assert [(s["name"], s["nodes"], s["state"]) for s in status["stations"]] == [
        ("north", [76, 77], "up"), ("south", [78], "up")]
    assert {n["node"]: n["station"] for n in status["nodes"]} == {
        76: "north", 77: "north", 78: "south"}
    assert status["link"]["port"] == north.path  # (the first station's, as one had it)

    sub = gw.subscribe("gx2/")
    sub.drain(2.0)
    stations = {(p["node"], p["station"]) for t, p in sub.messages if t[4].isdigit()}
    assert stations == {(76, "north"), (77, "north"), (78, "south")}
    # a command goes through the node's own base station
    assert gw.control.result("poll", node=78, record="euler")["station"] == "south"
    assert gw.control.result("poll", node=76, record="euler")["station"] == "north"

    before = [p for t, p in sub.messages if t == "gx2/78/accel_angrate"]
    north.unplug()
    wait_for(lambda: gw.status()["stations"][0]["state"] == "down", 5, "north's link down")

    def south_for_3_s() -> list[dict]:
        sub.messages.clear()
        sub.drain(3.0)
        return [p for t, p in sub.messages if t == "gx2/78/accel_angrate"]

    def latest(records: list[dict]) -> list[tuple[float, ...]]:
        """The five latest records (latency, host time, device time, seq): a late read
        shows in the host times, a clock misplaced in the latencies alone."""
        worst = sorted(records, key=lambda r: r["host_time"] - r["time"])[-5:]
        return [(round(r["host_time"] - r["time"], 4), r["host_time"], r["device_time"],
                 r["seq"], read_after(r)) for r in worst]

    def read_after(record: dict) -> float | None:
        """Seconds from the simulator's write of its packet to the gateway's read: a
        read late by the gateway's loop, or a write late by the simulator's."""
        at = written.get(record["timer"])
        return None if at is None else round(record["host_time"] - at, 4)

    def south_clock() -> dict:
        return next(n for n in gw.status()["nodes"] if n["node"] == 78).get("clock", {})

    def latency_p99(records: list[dict]) -> float:
        delays = sorted(r["host_time"] - r["time"] for r in records)
        return delays[int(0.99 * (len(delays) - 1))]

    # south's records keep their rate and their latency, and its commands go through.
    # A loop blocked by north's port (its close, a reopen each second) delays south's
    # records: their latency's p99 rises by the block (SIGSTOP of the gateway for 0.2 s
    # after the unplug: 19 -> 158 ms; at the p90 a block of 50 to 80 ms passed unseen).
    # The host's scheduling does that too, once, at any moment (0.1 to 0.4 s at 6 to 8
    # test processes on 2 cores, before the unplug as after it, though the test runs
    # favoured; twice running in two full runs of seven): a window whose p99 rose is
    # taken again, up to twice, and a block that comes with each reopen (three in each
    # window) shows in every one. One at the unplug alone is held to the gap.
    # The margin, 50 ms, lets a block of about 80 ms pass (p99 of 300 records: the
    # third worst); under load the p99 rose by 18 ms in both windows once.
    after = south_for_3_s()
    span = after[-1]["device_time"] - after[0]["device_time"]
    assert len(after) >= 0.95 * span * 100, (len(after), span)
    gaps = [b["host_time"] - a["host_time"] for a, b in pairwise(after)]
    assert max(gaps) < 0.5, max(gaps)
    for _ in range(2):
        if latency_p99(after) <= latency_p99(before) + 0.05:
            break
        after = south_for_3_s()
    assert latency_p99(after) <= latency_p99(before) + 0.05, (
        f"p99 {latency_p99(before):.4f} s before, {latency_p99(after):.4f} after; "
        f"latest {latest(after)}; 78's clock {south_clock()}")
    assert gw.control.result("poll", node=78, record="euler")["station"] == "south"
    nodes = {n["node"]: n for n in gw.status()["nodes"]}
    assert nodes[76]["state"] == "link down" and nodes[78]["state"] == "streaming"


def test_a_ping_of_nodes_on_two_stations_one_down_answers_for_each_node(simulator, gateway):
    """Issue 31, defect 10: node 78's station down made `ping 76 78` print nothing for
    76 and only "the base station is not connected"."""
    _, south, gw = two_stations(simulator, gateway)
    south.unplug()
    wait_for(lambda: gw.status()["stations"][1]["state"] == "down", 5, "south's link down")
    ran = gx2ctl("--config", str(gw.path), "ping", "76", "78")
    assert ran.status == 1, ran
    assert ran.stdout.splitlines() == [
        "76 answered", "78 not pinged: base station south is down (not connected)"], ran
    assert ran.stderr.strip() == "gx2ctl: 1 of 2 nodes did not answer: 78", ran
    nodes = json.loads(gx2ctl("--config", str(gw.path), "--json", "ping", "76", "78")
                       .stdout.splitlines()[0])["nodes"]
    assert nodes == [{"node": 76, "answered": True},
                     {"node": 78, "answered": False,
                      "error": "base station south is down (not connected)"}]
    # any other op on a node of the station that is down names the station too
    ran = gx2ctl("--config", str(gw.path), "poll", "78", "euler")
    assert (ran.status, ran.stderr.strip()) == (
        1, "gx2ctl: base station south is down (not connected)"), ran


def test_nodes_on_different_stations_share_one_clock(simulator, gateway):
    north, south, gw = two_stations(simulator, gateway)
    sub = gw.subscribe("gx2/76/accel_angrate", "gx2/78/accel_angrate")
    sub.drain(6.0)
    bias = {}
    for node, sim in ((76, north), (78, south)):
        records = [p for t, p in sub.messages if t == f"gx2/{node}/accel_angrate"]
        first = records[0]["device_time"]
        settled = [r for r in records if r["device_time"] - first > 3.0]
        assert len(settled) > 200
        bias[node] = statistics.median(errors(sim, node, settled, "time"))
    # as well as two nodes of one station agree (tests/e2e/test_sample_time.py)
    assert abs(bias[76] - bias[78]) <= 1.5e-3, bias


def test_a_recording_of_two_stations_keeps_each_ones_bytes_and_replays_identically(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    _, _, gw = two_stations(simulator, gateway, record={"directory": str(directory)})
    for node in (76, 78):  # (something written to each base station)
        gw.control.result("poll", node=node, record="euler")
    gw.subscribe("gx2/").drain(2.0)
    assert gw.terminate()[0] == 0, gw.log()
    entries = recorded(directory)
    topics = {topic for topic, _, _ in entries}
    assert {"serial/north", "serial/south", "serial/north/written",
            "serial/south/written"} <= topics
    assert "serial" not in topics
    live = {key: payload for key, (_, payload) in payloads(entries).items()}
    assert {node for node, _ in live} == {76, 77, 78}

    replays_identically(gateway, directory, live, [
        {"name": name, "nodes": nodes} for name, nodes in (
            ("north", [{"address": 76}, {"address": 77}]), ("south", [{"address": 78}]))])


def replays_identically(gateway, directory: Path, live: dict, stations: list[dict]) -> None:
    """``directory``'s recording, replayed through a ``replay://`` for each of
    ``stations``, publishes every record of ``live`` ((node, seq) -> payload) again,
    identical."""
    # subscribed from before the gateway binds (ZeroMQ connects once it does), not once
    # it answers, which can come after the replay's 2 s delay on a loaded machine (2,088
    # of 5,110 records were missed once, beside the suite's other processes)
    replay = gateway(None, [], wait=False, base_stations=[
        {**station, "port": f"replay://{directory}?speed=0&exit=true&delay=2"}
        for station in stations])
    sub = replay.subscribe("gx2/")
    wait_for(lambda: replay.proc.poll() is not None, 60, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()

    def all_read(messages: list) -> bool:
        return live.keys() <= {(p["node"], p["seq"]) for t, p in messages if t[4].isdigit()}
    with contextlib.suppress(AssertionError):  # (what is missing is said below)
        sub.until(all_read, 10, "every record read")
    played = {(p["node"], p["seq"]): strict(p) for t, p in sub.messages if t[4].isdigit()}
    missing = sorted(live.keys() - played.keys())
    assert not missing, (len(missing), len(live), missing[:5])
    for key, payload in live.items():
        for name, value in payload.items():
            if name in ("host_time", "time"):
                assert math.isclose(played[key][name], value, abs_tol=1e-6), (key, name)
            else:
                assert played[key][name] == value, (key, name)


@pytest.mark.parametrize(("stations", "words"), [
    ([{"port": "/dev/ttyUSB0", "nodes": [{"address": 76}]},
      {"port": "/dev/ttyUSB1", "nodes": [{"address": 76}]}],
     ["base_stations[1].nodes[0].address", "node 76", "base_stations[0] (station1)"]),
    ([{"port": "/dev/ttyUSB0", "nodes": [{"address": 76}]},
      {"port": "/dev/ttyUSB0", "nodes": [{"address": 77}]}],
     ["base_stations[1].port", "/dev/ttyUSB0", "base_stations[0] (station1)"]),
    ([{"name": "a", "port": "sim://", "nodes": [{"address": 76}]},
      {"name": "a", "port": "sim://", "nodes": [{"address": 77}]}],
     ["base_stations[1].name", "'a'"]),
    ([{"name": "north pole", "port": "sim://", "nodes": [{"address": 76}]}],
     ["base_stations[0].name"]),
])
def test_a_configuration_of_stations_that_cannot_work_is_refused_naming_both(
        tmp_path: Path, stations, words):
    path = tmp_path / "nodes.yaml"
    path.write_text(json.dumps({"base_stations": stations}))
    run = subprocess.run([script("gx2-gateway"), "--config", str(path), "--check"],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and len(run.stderr.splitlines()) == 1, run
    assert "Traceback" not in run.stderr
    for word in words:
        assert word in run.stderr, (word, run.stderr)


def test_both_forms_at_once_are_refused(tmp_path: Path):
    path = tmp_path / "nodes.yaml"
    path.write_text(json.dumps({"base_station": {"port": "sim://"}, "nodes": [76],
                                "base_stations": [{"port": "sim://", "nodes": [77]}]}))
    run = subprocess.run([script("gx2-gateway"), "--config", str(path), "--check"],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "either base_stations" in run.stderr, run
