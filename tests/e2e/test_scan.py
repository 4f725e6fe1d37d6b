"""gx2ctl scan through the installed gx2ctl and gx2-gateway, gx2-sim on a pty: a channel
with configured nodes, nodes the gateway does not know (one streaming, one polled) and
a configured node that is not there (unpowered); the scan finds exactly the nodes
present, reads them without writing, and the configured streams lose nothing meanwhile.
A station down, bad ranges, --json and Ctrl-C (a real SIGINT) as a user meets them."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess

from aspp.host_side import CommandPacket, PingRequest
from gateway.sim.node import FIRMWARE_VERSION, NodeSettings
from tests.helpers.processes import Running, gx2ctl, script, spawn_run
from tests.helpers.waiting import wait_for

INTERRUPTED = 130
READS = {0xE5, 0xE9, 0xEA}
"""What a scan may send a node: EEPROM reads, the firmware version, identifier strings."""


def present() -> list[NodeSettings]:
    """76 and 77 configured and streaming; 81 streaming euler at 50 Hz from power-up and
    90 polled, neither configured. (95 is configured, and absent: unpowered.)"""
    return [NodeSettings(76), NodeSettings(77, stream="euler"),
            NodeSettings(81, stream="euler", divider=1024, serial="4200-1081"),
            NodeSettings(90, model="3dm-gx2")]


CONFIGURED = [{"address": 76, "stream": "accel_angrate", "name": "left-wing"},
              {"address": 77, "stream": "euler"}, {"address": 95}]


def commands_to(sim, node: int) -> set[int]:
    """The command bytes the base station broadcast to ``node``."""
    return sim.call(lambda station, now: {
        event.command[0] for _, event in station.from_host_log
        if isinstance(event, CommandPacket) and event.node == node})


def pings(sim) -> list[int]:
    return sim.call(lambda station, now: [event.node for _, event in station.from_host_log
                                          if isinstance(event, PingRequest)])


def test_a_scan_of_1_to_100_finds_exactly_the_nodes_present_and_the_streams_lose_nothing(
        simulator, gateway):
    sim = simulator(*present())
    gw = gateway(sim.path, CONFIGURED)
    gw.wait_streaming(76, 77)
    sub = gw.subscribe("gx2/76/", "gx2/77/")
    sub.until(lambda m: {p["node"] for _, p in m} == {76, 77}, 5, "both streams")
    before = {n["node"]: n for n in gw.status()["nodes"]}

    ran = gx2ctl("--config", str(gw.path), "--json", "scan")

    assert ran.status == 0, ran
    assert ran.stderr == ""
    lines = ran.stdout.splitlines()
    assert len(lines) == 1, lines
    result = json.loads(lines[0])
    assert result["scanned"] == 100 and result["stations"] == ["station1"]
    assert result["interrupted"] is False
    found = {entry["address"]: entry for entry in result["found"]}
    assert list(found) == [76, 77, 81, 90]  # not 95: configured, but not powered
    assert sorted(set(pings(sim))) == list(range(1, 101))
    for entry in found.values():
        assert entry["station"] == "station1"
        assert isinstance(entry["lqi"], int) and isinstance(entry["rssi"], int)
        assert entry["rssi"] < 0
        assert entry["firmware"] == FIRMWARE_VERSION and entry["firmware_version"] == "2.1.13"
        assert entry["unanswered"] is None
    assert (found[76]["configured"], found[76]["name"], found[76]["streaming"]) == \
        (True, "left-wing", "accel_angrate")
    assert (found[77]["configured"], found[77]["streaming"]) == (True, "euler")
    stranger = found[81]
    assert (stranger["configured"], stranger["streaming"], stranger["auto_start"]) == \
        (False, "euler", "euler")
    assert (stranger["divider"], stranger["rate_hz"]) == (1024, 50.0)
    assert (stranger["serial_number"], stranger["model_name"]) == ("4200-1081", "Inertia-Link")
    polled = found[90]
    assert (polled["configured"], polled["streaming"], polled["auto_start"]) == \
        (False, None, None)
    assert (polled["model_name"], polled["model_number"], polled["rate_hz"]) == \
        ("3DM-GX2", "6220-0001", 100.0)
    for node in (81, 90):  # read, never written (nor started or stopped)
        assert commands_to(sim, node) <= READS, commands_to(sim, node)

    # the configured streams went on through the scan: every message published, in
    # order, none lost over the radio either
    after = {n["node"]: n for n in gw.status()["nodes"]}
    sub.drain(0.2)
    for node in (76, 77):
        seqs = [p["seq"] for p in sub.records(node)]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"node {node}: a gap"
        assert after[node]["state"] == "streaming"
        assert after[node]["lost_radio"] == before[node]["lost_radio"]
        assert after[node]["lost_gateway"] == 0
        streamed = [p for p in sub.records(node) if p["record"] == after[node]["record"]]
        assert len(streamed) > 100  # the scan's seconds, at 50 Hz and more


def test_the_text_lists_each_node_found_and_a_scan_that_finds_none_succeeds(simulator,
                                                                            gateway):
    sim = simulator(*present())
    gw = gateway(sim.path, CONFIGURED)
    ran = gx2ctl("--config", str(gw.path), "scan", "--addresses", "80-82,200")
    assert ran.status == 0, ran
    lines = ran.stdout.splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("81  station1  LQI ")
    assert ("Inertia-Link  serial 4200-1081  firmware 2.1.13  50 Hz (divider 1024)  "
            "streaming euler (from power-up: euler)  not configured") in lines[0]
    assert lines[1].startswith("scanned 4 addresses (80-82,200) on station1 in ")
    assert lines[1].endswith(": 1 node found")

    none = gx2ctl("--config", str(gw.path), "scan", "station1", "--addresses", "1-3")
    assert none.status == 0, none
    assert none.stdout.splitlines()[-1].endswith(": no node answered")


def test_a_station_that_is_down_is_exit_1_in_one_line(simulator, gateway):
    sim = simulator(*present())
    gw = gateway(sim.path, CONFIGURED)
    sim.unplug()
    wait_for(lambda: gw.status()["link"]["state"] == "down", 5, "the link down")
    ran = gx2ctl("--config", str(gw.path), "scan")
    assert ran.status == 1, ran
    assert ran.stdout == ""
    assert ran.stderr.splitlines() == [
        "gx2ctl: base station station1 is down (not connected): nothing scanned"]
    named = gx2ctl("--config", str(gw.path), "--json", "scan", "station1")
    assert named.status == 1, named
    assert json.loads(named.stdout)["exit"] == 1
    unknown = gx2ctl("--config", str(gw.path), "scan", "north")
    assert unknown.status == 2, unknown
    assert unknown.stderr.splitlines() == [
        "gx2ctl: no base station is named 'north' (this gateway has station1)"]


def test_malformed_ranges_and_addresses_out_of_range_are_exit_2_in_one_line():
    for ranges, said in [("0", "node address 0 is out of range 1..65534"),
                         ("65535", "node address 65535 is out of range 1..65534"),
                         ("1-65535", "node address 65535 is out of range 1..65534"),
                         ("10-5", "range '10-5' runs backwards"),
                         ("1-", "'1-' is not an address or a range of them"),
                         ("1,,3", "'' in '1,,3' is not an address or a range of them"),
                         ("x", "node address 'x' is not a number")]:
        ran = gx2ctl("--control", "ipc:///nonexistent/gx2", "--timeout", "1", "scan",
                     "--addresses", ranges)
        assert ran.status == 2, (ranges, ran)
        assert ran.stdout == ""
        lines = ran.stderr.splitlines()
        assert len(lines) == 1 and said in lines[0], (ranges, lines)


def test_ctrl_c_stops_the_scan_and_prints_what_it_found(simulator, gateway):
    sim = simulator(NodeSettings(3), NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    ctl = Running("gx2ctl", "--config", str(gw.path), "--json", "scan", "--addresses",
                  "1-1000")
    try:
        wait_for(lambda: len(pings(sim)) >= 20, 10, "20 addresses pinged")
        ctl.proc.send_signal(signal.SIGINT)
        assert ctl.finish(5) == INTERRUPTED, ctl.stderr
    finally:
        ctl.kill()
    assert [line.rstrip("\n") for line in ctl.stderr] == [
        "gx2ctl: interrupted: scan cancelled by the client; it only reads: no node was "
        "changed"]
    assert len(ctl.stdout) == 1, ctl.stdout
    result = json.loads(ctl.stdout[0])
    assert result["interrupted"] is True and result["of"] == 1000
    # 20 pinged: the third batch of 8 had begun, the two before it were answered (the
    # batch under way when Ctrl-C came is cancelled, and not counted)
    assert 16 <= result["scanned"] < 1000
    assert [entry["address"] for entry in result["found"]] == [3]
    wait_for(lambda: "scan cancelled by the client" in gw.log(), 5, "the gateway to log it")
    stopped = len(pings(sim))
    assert stopped < 1000
    # the gateway pings no more: a ping sent now is the last (but a scan's ping that
    # was on its way as the cancel came)
    assert gx2ctl("--config", str(gw.path), "ping", "76").status == 0
    assert pings(sim)[stopped:][-1:] == [76] and len(pings(sim)) <= stopped + 2


def test_a_gateway_with_no_nodes_yet_scans_the_channel(simulator, gateway):
    """Where a new user starts, not knowing the nodes' addresses: the base station
    alone (``nodes: []``), then a scan."""
    sim = simulator(*present())
    gw = gateway(sim.path, [])
    assert "0 nodes" in gx2ctl("--config", str(gw.path), "status").stdout + gw.log()
    ran = gx2ctl("--config", str(gw.path), "--json", "scan", "--addresses", "70-95")
    assert ran.status == 0, ran
    found = json.loads(ran.stdout)["found"]
    assert [(e["address"], e["configured"]) for e in found] == \
        [(76, False), (77, False), (81, False), (90, False)]
    assert [e["streaming"] for e in found] == [None, "euler", "euler", None]


def test_every_station_is_scanned_at_once_and_each_node_says_which(simulator, gateway):
    north = simulator(NodeSettings(76), NodeSettings(12), name="north")
    south = simulator(NodeSettings(78), NodeSettings(14), name="south")
    gw = gateway(None, [], base_stations=[
        {"name": "north", "port": north.path, "nodes": [{"address": 76}]},
        {"name": "south", "port": south.path, "nodes": [{"address": 78}]}])
    ran = gx2ctl("--config", str(gw.path), "--json", "scan", "--addresses", "1-80")
    assert ran.status == 0, ran
    result = json.loads(ran.stdout)
    assert result["stations"] == ["north", "south"] and result["scanned"] == 80
    assert [(e["address"], e["station"], e["configured"]) for e in result["found"]] == [
        (12, "north", False), (14, "south", False), (76, "north", True),
        (78, "south", True)]
    # each channel pinged every address once, the two at the same time: no longer than
    # one channel's scan takes alone
    assert sorted(pings(north)) == sorted(pings(south)) == list(range(1, 81))
    alone = gx2ctl("--config", str(gw.path), "--json", "scan", "south", "--addresses",
                   "1-80")
    assert [e["address"] for e in json.loads(alone.stdout)["found"]] == [14, 78]
    assert result["seconds"] < 1.6 * json.loads(alone.stdout)["seconds"]


def test_on_a_terminal_the_progress_is_shown_in_place_on_stderr(simulator, gateway):
    sim = simulator(NodeSettings(3))
    gw = gateway(sim.path, [])
    main, other = os.openpty()
    try:
        run = spawn_run([script("gx2ctl"), "--config", str(gw.path), "scan",
                         "--addresses", "1-40"], stdout=subprocess.PIPE, stderr=other,
                        stdin=subprocess.DEVNULL, text=True, timeout=60)
        os.close(other)
        shown = b""
        with contextlib.suppress(OSError):  # (EIO once the terminal's last writer is gone)
            while chunk := os.read(main, 4096):
                shown += chunk
    finally:
        os.close(main)
    assert run.returncode == 0, run
    text = shown.decode()
    steps = re.findall(r"\r\x1b\[Kgx2ctl: scan: (\d+) of 40 addresses, (\d) found"
                       r"(?:, about \d+ s left)?", text)
    done = [int(d) for d, _ in steps]
    assert done[0] == 0 and done[-1] == 40 and done == sorted(done) and len(done) >= 5, text
    assert "about" in text and text.endswith("\r\x1b[K"), text  # cleared at the end
    assert run.stdout.splitlines()[0].startswith("3  station1  LQI ")


def test_on_a_full_line_each_node_found_is_read_whole_and_nothing_unread_is_guessed(
        simulator, gateway):
    # five nodes streaming at 100 Hz fill the line: a read takes many times as long
    sim = simulator(*(NodeSettings(a, stream="accel_angrate", divider=512)
                      for a in range(76, 81)))
    gw = gateway(sim.path, [{"address": a, "stream": "accel_angrate"} for a in (76, 77, 78)])
    gw.wait_streaming(76, 77, 78)
    # (a node takes 6 to 7 s to read: more than one request's 4.5 s)
    ran = gx2ctl("--config", str(gw.path), "--json", "scan", "--addresses", "75,78,80",
                 timeout=90)
    assert ran.status == 0, ran
    found = json.loads(ran.stdout)["found"]
    assert [f["address"] for f in found] == [78, 80]
    for entry in found:  # a batch starts no node it cannot finish: the next one reads it
        assert entry["unanswered"] is None, ran.stdout
        assert entry["serial_number"] and entry["divider"] == 512, entry
    assert [f["auto_start"] for f in found] == ["accel_angrate"] * 2


def test_a_base_station_lost_mid_scan_keeps_what_was_found_and_says_how_far(
        simulator, gateway, tmp_path):
    for as_json in (True, False):
        name = "json" if as_json else "text"
        sim = simulator(NodeSettings(3), NodeSettings(76), name=name)
        gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}],
                     directory=tmp_path / f"gw-{name}")
        ctl = Running("gx2ctl", "--config", str(gw.path), *(["--json"] if as_json else []),
                      "scan", "--addresses", "1-1000")
        try:
            wait_for(lambda sim=sim: len(pings(sim)) >= 20, 10, "20 addresses pinged")
            sim.unplug()
            assert ctl.finish(15) == 1, ctl.stderr
        finally:
            ctl.kill()
        [said] = ctl.stderr
        assert said.startswith("gx2ctl: base station station1 "), said
        if as_json:
            [line] = ctl.stdout
            result = json.loads(line)
            assert [entry["address"] for entry in result["found"]] == [3]
            assert 16 <= result["scanned"] < 1000 and result["of"] == 1000
            assert result["exit"] == 1 and said.rstrip("\n") == f"gx2ctl: {result['error']}"
        else:
            found, last = ctl.stdout
            assert found.startswith("3  station1  LQI ")
            assert re.fullmatch(r"stopped after (\d+) addresses \(1-\1\) of 1000 on "
                                r"station1, [\d.]+ s: 1 node found\n", last), last
    # once down, a new scan has nothing to say but the error
    text = gx2ctl("--config", str(gw.path), "scan", "--addresses", "1-1000")
    assert text.status == 1 and text.stdout == "", text
