"""The ``gx2-sim`` console script, run as a user runs it: a subprocess, its output, its
exit status, and the port it serves, opened with pyserial."""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import re
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial

from aspp import TICKS_PER_SECOND, Decoder, Event, Frame, Reply, decode
from aspp import commands as gx2
from gateway.sim.cli import UNPLUG_SECONDS
from tests.helpers.processes import Running, script
from tests.helpers.waiting import wait_for

STARTUP = 60.0
"""Seconds allowed for the script to import and print its port: a bound that tells a
hang from a start, not a measure of one (a loaded CI machine was seen taking 13 s)."""
EXIT = 2.0
"""Seconds promised between a SIGTERM/SIGINT and the end of the simulator's shutdown:
its loop stopped and its thread joined, then the link removed with the pty."""
STALL_ALLOWANCE = 2.0
"""Seconds more for a loaded CI machine, which stalls a process (or the test's polling)
for a second or more. EXIT plus this still tells a prompt shutdown from one that waited
out a timeout (the simulator's thread join gives up after 5 s)."""
TEARDOWN = 10.0
"""Seconds allowed from the end of the shutdown to the exit being seen (the interpreter
tearing down, on a loaded machine seen at 4.6 s): a bound that tells a hang from an
exit, not a measure of one."""
DEADLINE = 10.0
"""Seconds a test waits for what normally arrives within milliseconds. Only a broken
simulator reaches it: a stall on a loaded machine must delay a test, not fail it."""


@pytest.fixture
def launch() -> Iterator[Callable[..., Running]]:
    started: list[Running] = []

    def start(*args: str) -> Running:
        running = Running("gx2-sim", *args)
        started.append(running)
        return running

    yield start
    for running in started:
        running.kill()


def read_events(ser: serial.Serial, decoder: Decoder,
                until: Callable[[list[Event]], bool], timeout: float = DEADLINE) -> list[Event]:
    """Short reads until ``until(events)`` holds; TimeoutError at the deadline."""
    deadline = time.monotonic() + timeout
    events: list[Event] = []
    while not until(events):
        if time.monotonic() >= deadline:
            raise TimeoutError(f"condition not met within {timeout} s: {len(events)} events")
        data = ser.read(4096)
        events += decoder.feed(data) if data else decoder.line_idle()
    return events


def replies(events: list[Event], node: int, command: int | None = None) -> list[Reply]:
    return [e for e in events if isinstance(e, Reply) and e.node == node
            and (command is None or e.command == command)]


def poll(ser: serial.Serial, decoder: Decoder, node: int, command: gx2.Command) -> Reply:
    ser.write(command.packet(node))
    events = read_events(ser, decoder, lambda ev: bool(replies(ev, node, command.code)))
    return replies(events, node, command.code)[0]


def pointing(link: Path) -> str | None:
    """Where ``link`` points, or None if it is not there."""
    with contextlib.suppress(OSError):
        return os.readlink(link)
    return None


def stops_cleanly(running: Running, signum: int, link: Path) -> None:
    """Send ``signum``: the simulator shuts down promptly (the link goes once its thread
    has stopped), and the process then exits with status 0 and no traceback."""
    assert pointing(link), "the link is there until the signal"
    signalled = time.monotonic()
    running.proc.send_signal(signum)
    deadline = signalled + EXIT + STALL_ALLOWANCE
    while pointing(link):
        if time.monotonic() >= deadline:
            raise AssertionError(f"the link is still there {EXIT} s (+{STALL_ALLOWANCE} s) "
                                 f"after the signal; exit {running.proc.poll()}, stderr "
                                 f"{running.stderr!r}")
        time.sleep(0.01)  # polling interval of a deadline-bounded wait
    assert running.finish(TEARDOWN) == 0, running.stderr
    assert not link.is_symlink() and not link.exists(), "the link is removed on exit"
    assert not any("Traceback" in line for line in running.stderr), running.stderr


# -- a running simulator ------------------------------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_serves_streaming_nodes_and_exits_cleanly_on_a_signal(
        launch: Callable[..., Running], tmp_path: Path, signum: int) -> None:
    link = tmp_path / "gx2"
    sim = launch("--nodes", "76,77", "--stream", "accel_angrate", "--link", str(link))
    banner = sim.wait_for_line(lambda line: "/dev/" in line, STARTUP)
    sim.wait_for_line(lambda line: line == str(link), STARTUP)
    pty = re.search(r"/dev/pts/\d+", banner)
    assert pty, f"the pty path is printed: {banner!r}"
    assert link.is_symlink() and os.readlink(link) == pty.group()

    with serial.Serial(str(link), 115200, timeout=0.01) as ser:
        events = read_events(ser, Decoder(), lambda ev: len(replies(ev, 76, 0xC2)) >= 5
                             and len(replies(ev, 77, 0xC2)) >= 5)
    for node in (76, 77):
        for reply in replies(events, node, 0xC2):
            rec = decode(reply.payload)
            assert rec.name == "accel_angrate"
            assert math.dist(rec["accel"], (0, 0, 0)) == pytest.approx(1.0, abs=0.01)
    assert {e.node for e in events if isinstance(e, Reply)} == {76, 77}

    stops_cleanly(sim, signum, link)


def test_config_file_with_two_nodes(launch: Callable[..., Running], tmp_path: Path) -> None:
    config = tmp_path / "sim.yaml"
    config.write_text("seed: 3\n"
                      "nodes:\n"
                      "  - address: 76\n"
                      "  - address: 300\n"
                      "    model: 3dm-gx2\n"
                      "    stream: euler\n"
                      "    divider: 1024\n")
    link = tmp_path / "gx2"
    sim = launch("--config", str(config), "--link", str(link))
    sim.wait_for_line(lambda line: line == str(link), STARTUP)

    with serial.Serial(str(link), 115200, timeout=0.01) as ser:
        decoder = Decoder()
        events = read_events(ser, decoder, lambda ev: len(replies(ev, 300, 0xCE)) >= 6)
        assert replies(events, 76) == [], "76 is polled: it does not stream"
        timers = [decode(r.payload).timer for r in replies(events, 300, 0xCE)]
        steps = {b - a for a, b in itertools.pairwise(timers)}
        assert steps == {round(1024 / 51200 * TICKS_PER_SECOND)}, "50 Hz, as configured"

        mag_300 = decode(poll(ser, decoder, 300, gx2.poll("mag")).payload)["mag"]
        assert all(math.isfinite(x) for x in mag_300), "a 3DM-GX2 has a magnetometer"
        mag_76 = decode(poll(ser, decoder, 76, gx2.poll("mag")).payload)["mag"]
        assert all(math.isnan(x) for x in mag_76), "76 is an Inertia-Link (the default)"
        name = decode(poll(ser, decoder, 300, gx2.device_id(2)).payload)["text"]
        assert name == "3DM-GX2"

    stops_cleanly(sim, signal.SIGTERM, link)


# -- bad arguments ------------------------------------------------------------------------


BAD = {
    # id: (arguments, config file text or None, words the one error line must contain)
    "node-0": (["--nodes", "0"], None, ["--nodes", "0", "out of range"]),
    "node-70000": (["--nodes", "76,70000"], None, ["--nodes", "70000", "out of range"]),
    "unknown-record": (["--nodes", "76", "--stream", "bogus_record"], None,
                       ["--stream", "bogus_record"]),
    "record-that-cannot-stream": (["--nodes", "76", "--stream", "eeprom_read"], None,
                                  ["eeprom_read", "stream"]),
    "divider-out-of-range": (["--nodes", "76", "--divider", "5"], None, ["divider"]),
    "no-nodes": ([], None, ["no nodes"]),
    "unknown-key": ([], "nodes:\n  - address: 76\n    colour: red\n",
                    ["{config}", "colour", "unknown key"]),
    "duplicate-address": ([], "nodes:\n  - address: 76\n  - address: 76\n",
                          ["{config}", "76", "twice"]),
    "both-config-and-nodes": (["--nodes", "76"], "nodes:\n  - address: 76\n", ["76"]),
    "unreadable-config": ([], "{missing}", ["{missing}", "cannot read"]),
    "config-is-a-directory": ([], "{directory}", ["{directory}", "cannot read"]),
    "invalid-yaml": ([], "nodes: [\n  - address: 76\n", ["{config}", "line"]),
}


@pytest.fixture(scope="module")
def bad_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict, object]]:
    """Every BAD case, run at once (each start-up costs most of a second of CPU)."""
    started = {}
    for case, (arguments, config_text, _) in BAD.items():
        tmp = tmp_path_factory.mktemp(case)
        config, missing = tmp / "sim.yaml", tmp / "absent.yaml"
        places = {"config": str(config), "missing": str(missing), "directory": str(tmp)}
        arguments = list(arguments)
        if config_text == "{missing}":
            arguments += ["--config", str(missing)]
        elif config_text == "{directory}":
            arguments += ["--config", str(tmp)]
        elif config_text is not None:
            config.write_text(config_text)
            arguments += ["--config", str(config)]
        proc = subprocess.Popen([script("gx2-sim"), *arguments, "--link", str(tmp / "gx2")],
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        started[case] = (tmp, places, proc)
    results = {}
    try:
        for case, (tmp, places, proc) in started.items():
            stdout, stderr = proc.communicate(timeout=60)
            results[case] = (tmp, places, (proc.returncode, stdout, stderr))
    finally:
        for _, _, proc in started.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return results


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_arguments_exit_2_with_one_line(bad_runs: dict, case: str) -> None:
    tmp, places, (returncode, stdout, stderr) = bad_runs[case]
    words = BAD[case][2]
    assert returncode == 2, (returncode, stderr)
    lines = stderr.splitlines()
    assert len(lines) == 1, f"exactly one line on stderr, got {stderr!r}"
    assert "Traceback" not in stderr
    line = lines[0]
    assert line.startswith("gx2-sim: ")
    for word in words:
        assert word.format(**places) in line, f"{word.format(**places)!r} not in {line!r}"
    assert stdout == "", "nothing is served"
    assert not (tmp / "gx2").is_symlink()


@pytest.mark.parametrize("signum", [signal.SIGUSR1, signal.SIGUSR2], ids=["reboot", "unplug"])
def test_signals_trigger_reboot_and_unplug(launch: Callable[..., Running], tmp_path: Path,
                                           signum: signal.Signals) -> None:
    """Triggers for a person at the demo: SIGUSR1 reboots every node (discovery frames
    arrive), SIGUSR2 unplugs the base station (the link goes away and comes back)."""
    link = tmp_path / "gx2"
    running = launch("--nodes", "76,77", "--link", str(link))
    running.wait_for_line(lambda line: line == str(link), STARTUP)
    old_pty = pointing(link)
    with serial.Serial(str(link), 115200, timeout=0.05) as port:  # (opening flushes it)
        running.proc.send_signal(signum)
        if signum == signal.SIGUSR1:
            events = read_events(port, Decoder(), lambda ev: len(
                [e for e in ev if type(e) is Frame]) >= 2)
            frames = [e for e in events if type(e) is Frame]
            assert sorted(f.node for f in frames) == [76, 77]
            assert all(f.is_discovery for f in frames)
        else:
            # the device goes: the open port fails (a stall cannot hide that, as it
            # could hide the two seconds the link is away) ...
            deadline = time.monotonic() + DEADLINE
            while True:
                try:
                    port.read(4096)
                except serial.SerialException:
                    break
                assert time.monotonic() < deadline, f"the port still works {DEADLINE} s on"
            # ... the link goes with it (it is removed before the pty is closed) ...
            assert pointing(link) != old_pty, "the link still points to the unplugged pty"
            # ... and a new device comes back behind the same link
            wait_for(lambda: pointing(link) not in (None, old_pty),
                       UNPLUG_SECONDS + DEADLINE, "the link to a new pty")
    stops_cleanly(running, signal.SIGTERM, link)
