"""``gx2ctl top`` in a real terminal: tmux runs it in an 80x24 pane against the
installed gateway on gx2-sim's pty; the test reads the screen and types keys as an
operator would."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.sim.node import NodeSettings
from tests.helpers.gateway import RunningGateway
from tests.helpers.processes import STARTUP, Running, script
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None,
                                reason="tmux is not installed (Debian: apt-get install tmux)")
WIDTH, HEIGHT = 80, 24
COLOUR = re.compile(r"\x1b\[[0-9;]*3[0-7](;[0-9]+)*m")
"""An SGR sequence that sets a foreground colour."""
ESCAPE = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


class Terminal:
    """One tmux server of the test's own, one WIDTH x HEIGHT window running a command."""

    def __init__(self, command: str, directory: Path, env: dict[str, str] | None = None):
        self.socket = f"gx2-test-{uuid.uuid4().hex[:8]}"
        self.exit_file = directory / f"{self.socket}.exit"
        wrapped = f"{command}; echo $? > {shlex.quote(str(self.exit_file))}; sleep 600"
        settings = [arg for key, value in (env or {}).items() for arg in ("-e", f"{key}={value}")]
        self.tmux("new-session", "-d", "-s", "top", "-x", str(WIDTH), "-y", str(HEIGHT),
                  *settings, wrapped)

    def tmux(self, *args: str) -> str:
        return subprocess.run(["tmux", "-L", self.socket, "-f", os.devnull, *args],
                              check=True, capture_output=True, text=True, timeout=10).stdout

    def screen(self, escapes: bool = False) -> list[str]:
        """The visible screen, a line per row; wrapped lines joined (``-J``), so a row
        that did not fit shows as one line longer than the width."""
        return [line.rstrip() for line in self.tmux(
            "capture-pane", "-p", "-J", *(["-e"] if escapes else []), "-t", "top").splitlines()]

    def history(self) -> str:
        """Everything the pane ever scrolled off, and the screen."""
        return self.tmux("capture-pane", "-p", "-J", "-S", "-", "-E", "-", "-t", "top")

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", "top", *keys)

    def exit_status(self) -> int | None:
        text = self.exit_file.read_text().strip() if self.exit_file.exists() else ""
        return int(text) if text else None

    def close(self) -> None:
        subprocess.run(["tmux", "-L", self.socket, "kill-server"], capture_output=True,
                       timeout=10, check=False)


@pytest.fixture
def terminals(tmp_path: Path) -> Iterator[list[Terminal]]:
    opened: list[Terminal] = []
    yield opened
    for terminal in opened:
        terminal.close()


def row(screen: list[str], node: int) -> str | None:
    return next((line for line in screen if line.startswith(f"{node} ")), None)


def rate(line: str | None) -> float:
    """The rate a row shows against its expected 100 Hz (0 if it shows none)."""
    found = re.search(r" (\d+\.\d)/100 ", line or "")
    return float(found.group(1)) if found else 0.0


def shows_both_streams(screen: list[str]) -> bool:
    left, right = row(screen, 76), row(screen, 77)
    return bool(left and right and "accel_ang" in left and "euler" in right
                and rate(left) > 50 and rate(right) > 50)


def test_top_shows_every_node_in_place_fits_80_columns_and_quits_on_q(
        simulator, gateway, terminals, tmp_path) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "name": "left-wing", "stream": "accel_angrate"},
                            {"address": 77, "name": "right-wing", "stream": "euler"}])
    command = f"{shlex.quote(script('gx2ctl'))} --config {shlex.quote(str(gw.path))} " \
              "--timeout 1 top"
    terminal = Terminal(command, tmp_path)
    terminals.append(terminal)

    screen = wait_for(lambda: (s := terminal.screen()) and shows_both_streams(s) and s,
                      STARTUP, "both nodes on the screen with their records and rates")
    assert all(len(line) <= WIDTH for line in screen), screen  # no row wrapped
    assert screen[0].startswith("gx2-gateway "), screen
    assert re.fullmatch(r"76 left-w\S* +streaming +accel_ang\S* .* (OK|WARN)",
                        row(screen, 76) or ""), screen
    header = next(line for line in screen if line.startswith("node "))
    for column in ("state", "record", "Hz", "lost", "RSSI", "health"):
        assert f" {column}" in header, header

    # refreshed in place: the screen changes, the table is drawn once, nothing scrolls
    first_time = re.search(r"\d\d:\d\d:\d\d", screen[0])
    assert first_time is not None, screen[0]
    wait_for(lambda: first_time.group() not in terminal.screen()[0], 5, "a redraw")
    everything = terminal.history()
    assert everything.count("gx2-gateway ") == 1, everything
    assert everything.count("\nnode ") == 1, everything
    coloured = next((line for line in terminal.screen(escapes=True)
                     if ESCAPE.sub("", line).startswith("76 ")), "")
    assert re.search(r"\x1b\[32m(OK|WARN)|\x1b\[[0-9;]*33m(WARN)", coloured), \
        f"node 76's health is in colour on a terminal: {coloured!r}"

    terminal.keys("q")
    assert wait_for(lambda: terminal.exit_status() is not None, 5, "top to quit on q") \
        is not None
    assert terminal.exit_status() == 0


def test_top_keeps_working_when_the_gateway_restarts(simulator, gateway, terminals,
                                                     tmp_path, zmq_context) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}])
    terminal = Terminal(f"{shlex.quote(script('gx2ctl'))} --config "
                        f"{shlex.quote(str(gw.path))} --timeout 1 top", tmp_path,
                        env={"NO_COLOR": "1"})
    terminals.append(terminal)
    wait_for(lambda: shows_both_streams(terminal.screen()), STARTUP, "both streams")
    assert not COLOUR.search("\n".join(terminal.screen(escapes=True))), "NO_COLOR is kept"

    status, _ = gw.terminate()
    assert status == 0
    wait_for(lambda: any("no heartbeat for" in line for line in terminal.screen()), 10,
             "top to say the gateway has gone quiet")
    assert row(terminal.screen(), 76) is not None  # the last status stays shown
    again = RunningGateway(gw.config, tmp_path, zmq_context)
    try:
        wait_for(lambda: any("the gateway restarted" in line for line in terminal.screen())
                 and shows_both_streams(terminal.screen()), STARTUP + 10,
                 "top to show the restarted gateway's nodes streaming")
    finally:
        again.terminate()
        again.close()
    terminal.keys("C-c")
    wait_for(lambda: terminal.exit_status() is not None, 5, "top to quit on Ctrl-C")
    assert terminal.exit_status() == 0


def test_top_greys_every_row_once_a_heartbeat_is_missed(simulator, gateway, terminals,
                                                        tmp_path) -> None:
    """Issue 31, defect 17: a killed gateway's rows stayed green OK, and the header said
    nothing until three heartbeats (or --timeout) had passed."""
    heartbeat = 2.0
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}],
                 publish={"heartbeat_s": heartbeat})
    terminal = Terminal(f"{shlex.quote(script('gx2ctl'))} --config "
                        f"{shlex.quote(str(gw.path))} top", tmp_path)
    terminals.append(terminal)
    wait_for(lambda: shows_both_streams(terminal.screen()), STARTUP, "both streams")

    def stale(screen: list[str]) -> bool:
        rows = [row(screen, 76) or "", row(screen, 77) or ""]
        return (any(line.startswith("no heartbeat for ") and f"one is due every "
                    f"{heartbeat:g} s" in line for line in screen)
                and all(re.search(r" stale \d+\.\ds$", line) for line in rows))
    gw.proc.kill()
    killed = time.monotonic()
    wait_for(lambda: stale(terminal.screen()), 1.5 * heartbeat,
             "the header to say a heartbeat was missed and the rows to turn stale")
    assert time.monotonic() - killed <= 1.5 * heartbeat
    screen = terminal.screen(escapes=True)
    rows = [line for line in screen if ESCAPE.sub("", line).startswith(("76 ", "77 "))]
    # grey and no colour (no green OK); tmux writes an attribute where it changes, so
    # the dim is at the start of the first row and carries on
    assert not any(COLOUR.search(line) for line in rows), rows
    assert re.match(r"(\x1b\[[0-9;]*m)*\x1b\[(\d*;)*2m", rows[0]), rows


def test_top_without_a_terminal_prints_plain_frames(simulator, gateway) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "name": "the left wing's outer tip",
                             "stream": "accel_angrate"}, {"address": 77, "stream": "euler"}])
    # a pipe, 40 columns, and an output that cannot carry "…": plain ASCII, cut with "~"
    top = Running("gx2ctl", "--config", str(gw.path), "top", "76",
                  env={**os.environ, "COLUMNS": "40", "PYTHONIOENCODING": "ascii"})
    try:
        # (not the rate's column: at 40 cells it shows or gives way by the width of its
        # value, "99.8/100" or "100.2/100", as the table fits what it has)
        top.wait_for_line(lambda line: line.startswith("76 ") and "streaming" in line,
                          STARTUP)
        top.wait_for_line(lambda line: line.startswith("gx2-gateway "), 5)  # a second frame
        top.proc.terminate()
        assert top.finish(5) == 0
    finally:
        top.kill()
    output = "".join(top.stdout)
    assert "\x1b" not in output, "no escape sequence in a pipe"
    assert output.isascii() and "~" in output, output
    assert all(len(line) <= 40 for line in output.splitlines()), output
    assert not any(line.startswith("77 ") for line in output.splitlines())  # only 76
    assert "q quits" not in output and top.stderr == []

    # JSON lines of the nodes asked for; a reader that stops reading ends it quietly
    run = subprocess.run(["bash", "-c", "set -o pipefail; " + shlex.join(
        [script("gx2ctl"), "--config", str(gw.path), "--json", "top", "77"]) + " | head -1"],
        capture_output=True, text=True, timeout=STARTUP)
    assert run.returncode == 0 and run.stderr == "", run
    heartbeat = json.loads(run.stdout)
    assert [n["node"] for n in heartbeat["nodes"]] == [77]
    assert heartbeat["link"]["state"] == "up"
