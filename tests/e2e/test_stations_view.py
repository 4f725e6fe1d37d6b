"""What an operator reads of a gateway of several base stations, through the installed
gx2ctl against real gx2-sim ptys: ``status`` fits 80 and 120 columns and groups nodes by
station with each line's share (``--wide`` shows every column), ``status --check``
fails when any station is down, and ``top`` in a real terminal groups them too."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess

import pytest

from gateway.ctl.statusview import NODE_COLUMNS
from tests.e2e.test_stations import two_stations
from tests.e2e.test_top import HEIGHT, WIDTH, Terminal, row
from tests.helpers.processes import STARTUP, script
from tests.helpers.waiting import wait_for


def gx2ctl(gw, *args: str, columns: int | None = None) -> subprocess.CompletedProcess:
    env = {key: value for key, value in os.environ.items() if key != "COLUMNS"}
    if columns is not None:
        env["COLUMNS"] = str(columns)
    return subprocess.run([script("gx2ctl"), "--config", str(gw.path), *args],
                          capture_output=True, text=True, timeout=30, env=env)


def table_of(output: str) -> list[str]:
    lines = output.splitlines()
    return lines[lines.index("") + 1:]


def test_status_fits_the_terminal_and_groups_nodes_by_station(simulator, gateway) -> None:
    _, south, gw = two_stations(simulator, gateway)
    shown = {}
    for columns in (80, 120):
        run = gx2ctl(gw, "status", columns=columns)
        assert run.returncode == 0 and run.stderr == "", run
        widest = max(run.stdout.splitlines(), key=len)
        assert len(widest) <= columns, widest
        table = table_of(run.stdout)
        shown[columns] = table[0].split()
        # each station's heading (its state and its line's share), then its nodes
        north_at = next(i for i, line in enumerate(table) if line.startswith("-- north (up, line "))
        south_at = next(i for i, line in enumerate(table) if line.startswith("-- south (up, line "))
        assert [line.split()[0] for line in table[north_at + 1:south_at]] == ["76", "77"]
        assert table[south_at + 1].split()[0] == "78"
    assert {"node", "state", "record", "health"} <= set(shown[80])
    assert len(shown[80]) < len(shown[120])

    wide = gx2ctl(gw, "status", "--wide", columns=80)
    assert wide.returncode == 0, wide
    assert table_of(wide.stdout)[0].split()[:2] == ["node", "name"]
    assert f" {NODE_COLUMNS[-2].header} " in table_of(wide.stdout)[0]  # every column
    assert max(len(line) for line in wide.stdout.splitlines()) > 80

    assert gx2ctl(gw, "status", "--check").returncode == 0
    south.unplug()
    wait_for(lambda: gw.status()["stations"][1]["state"] != "up", 5, "south's link down")
    check = gx2ctl(gw, "status", "--check")
    assert check.returncode == 1, check
    assert "1 of 2 base stations not up: south" in check.stderr, check


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_top_groups_nodes_under_their_station_with_its_line_share(
        simulator, gateway, tmp_path) -> None:
    _, _, gw = two_stations(simulator, gateway)
    terminal = Terminal(f"{shlex.quote(script('gx2ctl'))} --config "
                        f"{shlex.quote(str(gw.path))} --timeout 1 top", tmp_path)
    try:
        see_grouped(terminal)
    finally:
        terminal.close()


def see_grouped(terminal: Terminal) -> None:

    def grouped() -> list[str] | None:
        screen = terminal.screen()
        heads = [i for i, line in enumerate(screen) if line.startswith(("north: ", "south: "))]
        if len(heads) != 2 or not all(row(screen, node) for node in (76, 77, 78)):
            return None
        return screen
    screen = wait_for(grouped, STARTUP, "both stations with their nodes on the screen")
    assert len(screen) <= HEIGHT and all(len(line) <= WIDTH for line in screen), screen
    assert any(line.startswith("base stations 2: 2 up") for line in screen), screen
    north = next(i for i, line in enumerate(screen) if line.startswith("north: up"))
    south = next(i for i, line in enumerate(screen) if line.startswith("south: up"))
    assert "% of 11,520 B/s" in screen[north] and "% of 11,520 B/s" in screen[south]
    assert [line.split()[0] for line in screen[north + 1:south]] == ["76", "77"]
    assert screen[south + 1].split()[0] == "78"
    terminal.keys("q")
    wait_for(lambda: terminal.exit_status() is not None, 5, "top to quit on q")
