"""One ``gx2-sim`` serving several base stations (``base_stations:`` in --config, issue
22), run as a user runs it: each station on its own pty behind its own link, with its
own nodes; the signals reach every station; a bad file is one line and exit 2."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from aspp import Decoder, Event, Frame, Reply
from gateway.sim import control
from gateway.sim.cli import UNPLUG_SECONDS
from tests.helpers.processes import Running, script, spawn_run
from tests.helpers.waiting import wait_for
from tests.sim.test_cli import DEADLINE, STARTUP, pointing, read_events, stops_cleanly

REPO = Path(__file__).resolve().parents[2]
TWO_STATIONS = """\
base_stations:
  - name: north
    link: {tmp}/north
    nodes:
      - {{address: 76, stream: accel_angrate}}
      - {{address: 77, stream: accel_angrate}}
  - name: south
    link: {tmp}/south
    seed: 2
    line: {{nack: 0.0}}
    nodes:
      - {{address: 78, stream: accel_angrate}}
"""
OWN_NODES = {"north": {76, 77}, "south": {78}}


@pytest.fixture
def two_stations(tmp_path: Path) -> Iterator[tuple[Running, dict[str, Path]]]:
    """gx2-sim with TWO_STATIONS, once it has said where each station is."""
    config = tmp_path / "stations.yaml"
    config.write_text(TWO_STATIONS.format(tmp=tmp_path))
    links = {name: tmp_path / name for name in OWN_NODES}
    running = Running("gx2-sim", "--config", str(config))
    try:
        for name, link in links.items():
            running.wait_for_line(lambda line, n=name, p=link: line == f"{n}: {p}", STARTUP)
        yield running, links
    finally:
        running.kill()


def nodes_seen(events: list[Event]) -> set[int]:
    return {e.node for e in events if isinstance(e, Reply)}


def discovered(events: list[Event]) -> list[int]:
    return sorted(e.node for e in events if type(e) is Frame and e.is_discovery)


def test_each_station_serves_its_own_nodes_and_a_reboot_reaches_every_station(
        two_stations: tuple[Running, dict[str, Path]]) -> None:
    running, links = two_stations
    ptys = {name: pointing(link) for name, link in links.items()}
    assert all(ptys.values()) and len(set(ptys.values())) == 2, ptys
    ports = {name: serial.Serial(str(link), 115200, timeout=0.01)
             for name, link in links.items()}
    try:
        for name, port in ports.items():
            events = read_events(port, Decoder(), lambda ev, n=name: all(
                len([e for e in ev if isinstance(e, Reply) and e.node == node]) >= 5
                for node in OWN_NODES[n]))
            assert nodes_seen(events) == OWN_NODES[name], f"{name} carries only its nodes"

        running.proc.send_signal(signal.SIGUSR1)  # every node of every station reboots
        for name, port in ports.items():
            events = read_events(port, Decoder(), lambda ev, n=name: len(
                discovered(ev)) >= len(OWN_NODES[n]))
            assert discovered(events) == sorted(OWN_NODES[name])
    finally:
        for port in ports.values():
            port.close()
    stops_cleanly(running, signal.SIGTERM, links["north"])
    assert not links["south"].is_symlink(), "every station's link is removed on exit"


def test_an_unplug_reaches_every_station(
        two_stations: tuple[Running, dict[str, Path]]) -> None:
    running, links = two_stations
    old = {name: pointing(link) for name, link in links.items()}
    # each port held open: its pty cannot be freed and its number given back at the replug
    ports = {name: serial.Serial(str(link), 115200, timeout=0.05)
             for name, link in links.items()}
    try:
        running.proc.send_signal(signal.SIGUSR2)
        for name, port in ports.items():
            wait_for(lambda p=port: unplugged(p), DEADLINE, f"{name}'s port to fail")
        for name, link in links.items():
            wait_for(lambda p=link, n=name: pointing(p) not in (None, old[n]),
                     UNPLUG_SECONDS + DEADLINE, f"{name}'s link to a new pty")
    finally:
        for port in ports.values():
            port.close()
    stops_cleanly(running, signal.SIGTERM, links["north"])
    assert not links["south"].is_symlink()


def sim_command(*args: str) -> subprocess.CompletedProcess:
    return spawn_run([script("gx2-sim"), *args], capture_output=True, text=True,
                     timeout=30, stdin=subprocess.DEVNULL)


def test_gx2_sim_unplug_name_unplugs_that_station_alone_until_replugged(
        two_stations: tuple[Running, dict[str, Path]]) -> None:
    """``gx2-sim unplug north`` from another shell: north's port fails while south's
    keeps streaming; ``gx2-sim replug north`` brings north back behind its link."""
    running, links = two_stations
    pid = str(running.proc.pid)
    old = {name: pointing(link) for name, link in links.items()}
    ports = {name: serial.Serial(str(link), 115200, timeout=0.05)
             for name, link in links.items()}
    try:
        done = sim_command("unplug", "north", "--seconds", "0", "--pid", pid)
        assert done.returncode == 0, done
        assert done.stdout.strip() == "north unplugged until replugged", done
        wait_for(lambda: unplugged(ports["north"]), DEADLINE, "north's port to fail")
        events = read_events(ports["south"], Decoder(), lambda ev: len(
            [e for e in ev if isinstance(e, Reply) and e.node == 78]) >= 20)
        assert nodes_seen(events) == {78}, "south streams on"
        assert not unplugged(ports["south"]) and pointing(links["south"]) == old["south"]
        assert pointing(links["north"]) is None, "north stays unplugged (--seconds 0)"

        done = sim_command("replug", "north", "--pid", pid)
        assert done.returncode == 0 and done.stdout.strip() == "north plugged in", done
        wait_for(lambda: pointing(links["north"]) not in (None, old["north"]), DEADLINE,
                 "north's link to a new pty")
    finally:
        for port in ports.values():
            port.close()
    with serial.Serial(str(links["north"]), 115200, timeout=0.05) as north:
        read_events(north, Decoder(), lambda ev: OWN_NODES["north"] <= nodes_seen(ev))
    stops_cleanly(running, signal.SIGTERM, links["north"])


def test_gx2_sim_unplug_of_a_name_no_station_has_says_which_there_are(
        two_stations: tuple[Running, dict[str, Path]]) -> None:
    running, _ = two_stations
    done = sim_command("unplug", "west", "--pid", str(running.proc.pid))
    assert done.returncode == 1, done
    assert done.stderr.strip() == ("gx2-sim: no running gx2-sim has a station west "
                                   "(stations: north, south)"), done
    done = sim_command("unplug", "--pid", str(running.proc.pid))
    assert done.returncode == 1 and "name a station" in done.stderr, done
    done = sim_command("unplug", "north", "--seconds", "soon")
    assert done.returncode == 2 and "'soon' is not a number" in done.stderr, done
    # what the socket is told is bounded as the command line's option is
    pid = running.proc.pid
    path = control.running(pid)[pid]
    for seconds in ("-1", "nan", "inf", "1e9"):
        answer = control.ask(path, f"unplug north {seconds}")
        assert not answer.startswith("ok") and "is not from 0 to 86400" in answer, answer


def unplugged(port: serial.Serial) -> bool:
    """Whether reading ``port`` fails, as it does once its device is gone."""
    try:
        port.read(4096)
    except serial.SerialException:
        return True
    return False


def test_the_example_file_is_valid() -> None:
    config = REPO / "config" / "sim-stations.yaml"
    done = subprocess.run([script("gx2-sim"), "--config", str(config), "--check"],
                          capture_output=True, text=True, timeout=STARTUP,
                          stdin=subprocess.DEVNULL)
    assert (done.returncode, done.stderr) == (0, ""), done
    assert done.stdout == f"{config}: valid (5 nodes on 3 base stations)\n"


def station(name: str, *addresses: int, link: str = "") -> str:
    nodes = ", ".join(f"{{address: {a}}}" for a in addresses)
    return f"  - name: {name}\n" + (f"    link: {link}\n" if link else "") + \
        f"    nodes: [{nodes}]\n"


BAD = {
    # id: (config text, more arguments, words the one error line must contain); {tmp}
    # is the case's directory, which holds "taken", a regular file
    "address-on-two-stations": (
        "base_stations:\n" + station("north", 76, 77, link="{tmp}/north")
        + station("south", 78, 77), [],
        ["base_stations[1].nodes[1].address", "77", "base_stations[0] (north)"]),
    "name-twice": (
        "base_stations:\n" + station("north", 76) + station("north", 78), [],
        ["base_stations[1].name", "'north'", "base_stations[0]"]),
    "link-twice": (
        "base_stations:\n" + station("north", 76, link="{tmp}/north")
        + station("south", 78, link="{tmp}/north"), [],
        ["base_stations[1].link", "{tmp}/north", "base_stations[0] (north)"]),
    "both-forms": (
        "nodes: [{address: 79}]\nbase_stations:\n" + station("north", 76), [],
        ["nodes", "either base_stations", "not both"]),
    "name-missing": ("base_stations:\n  - nodes: [{address: 76}]\n", [],
                     ["base_stations[0].name", "missing"]),
    "unknown-key": ("base_stations:\n" + station("north", 76) + "    colour: red\n", [],
                    ["base_stations[0].colour", "unknown key"]),
    "nodes-option": ("base_stations:\n" + station("north", 76), ["--nodes", "80"],
                     ["--nodes", "base_stations"]),
    "link-option": ("base_stations:\n" + station("north", 76), ["--link", "{tmp}/gx2"],
                    ["--link", "base_stations"]),
    # the first station is up when the second's link is refused: it goes too
    "second-link-taken": (
        "base_stations:\n" + station("north", 76, link="{tmp}/north")
        + station("south", 78, link="{tmp}/taken"), [],
        ["south", "{tmp}/taken", "not a symlink"]),
}


def placed(text: str, tmp: Path) -> str:
    """``text`` with {tmp} the case's directory (YAML's own braces left alone)."""
    return text.replace("{tmp}", str(tmp))


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, object]]:
    """Every BAD case, run at once (each start-up costs most of a second of CPU)."""
    started = {}
    for case, (text, arguments, _) in BAD.items():
        tmp = tmp_path_factory.mktemp(case)
        (tmp / "taken").write_text("someone's file")
        config = tmp / "stations.yaml"
        config.write_text(placed(text, tmp))
        command = [script("gx2-sim"), "--config", str(config),
                   *(placed(a, tmp) for a in arguments)]
        started[case] = (tmp, subprocess.Popen(command, stdin=subprocess.DEVNULL,
                                               stdout=subprocess.PIPE,
                                               stderr=subprocess.PIPE, text=True))
    results = {}
    try:
        for case, (tmp, proc) in started.items():
            stdout, stderr = proc.communicate(timeout=STARTUP)
            results[case] = (tmp, (proc.returncode, stdout, stderr))
    finally:
        for _, proc in started.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return results


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_a_bad_stations_file_exits_2_with_one_line(bad_runs: dict, case: str) -> None:
    tmp, (returncode, stdout, stderr) = bad_runs[case]
    assert returncode == 2, (returncode, stderr)
    assert len(stderr.splitlines()) == 1, f"exactly one line on stderr, got {stderr!r}"
    line = stderr.splitlines()[0]
    assert line.startswith("gx2-sim: ") and "Traceback" not in stderr
    for word in BAD[case][2]:
        assert placed(word, tmp) in line, f"{placed(word, tmp)!r} not in {line!r}"
    assert stdout == "", "nothing is served"
    assert [p.name for p in tmp.iterdir() if p.is_symlink()] == [], "no link is left"
    assert (tmp / "taken").read_text() == "someone's file"

