"""Ports that cannot be opened (issue 31): a base station behind a network serial
server that does not answer, whose opens hang while no other station, request or
shutdown waits for them; and a port another process holds, said in plain words."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tty
from collections.abc import Iterator
from itertools import pairwise

import pytest

from tests.helpers.processes import EXIT, STARVED, Ran, gx2ctl
from tests.helpers.waiting import wait_for

HANG_CHECK = 1.0
"""Seconds a probe connect must go unanswered for the listener to count as hanging."""
READ_MARGIN = 0.25
"""Seconds a station's record may come later than its stream's period while another
station's open hangs: the scheduling a loaded 2-core host adds (154 ms seen), well
under the 5 s an open on the loop holds every station."""


@pytest.fixture
def hanging_port() -> Iterator[int]:
    """A loopback TCP port whose connects hang: a listener with ``listen(0)`` whose
    accept queue is filled with connections it never accepts. Linux then drops every
    further SYN, so a connect waits for its own timeout (pyserial's: 5 s)."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(0)
    port = listener.getsockname()[1]
    fillers: list[socket.socket] = []

    def hangs() -> bool:
        probe = socket.socket()
        probe.settimeout(HANG_CHECK)
        try:
            probe.connect(("127.0.0.1", port))
        except TimeoutError:
            probe.close()
            return True
        fillers.append(probe)  # it got in: one more that fills the queue
        return False
    try:
        wait_for(hangs, 10 * HANG_CHECK, "a connect to the filled listener to hang")
        yield port
    finally:
        for filler in fillers:
            filler.close()
        listener.close()


def test_a_station_whose_open_hangs_delays_no_other_and_shows_opening(gateway,
                                                                      hanging_port):
    gw = gateway(None, [], wait=False, base_stations=[
        {"name": "good", "port": "sim://", "nodes": [{"address": 76, "stream": "euler"}]},
        {"name": "remote", "port": f"socket://127.0.0.1:{hanging_port}",
         "nodes": [{"address": 77}]}])
    sub = gw.subscribe("gx2/76/")
    sub.until(lambda m: len(m) > 10, 20, "good's records")
    # long enough for remote's open to hang to its end (pyserial's 5 s) and be tried
    # again (on the loop, each attempt stalled every station for those 5 s)
    sub.drain(6.0)
    arrived = [p["host_time"] for _, p in sub.messages]
    gaps = [b - a for a, b in pairwise(arrived)]
    # good's records are read as they come (add_reader), one its stream's period
    # (10 ms) apart: a longer gap is the loop held from its reads. An open on the loop
    # held it for the whole hang (a 5.02 s gap); beside the loop, good's largest gap
    # was 17 to 81 ms idle and 18 to 154 ms with a CPU-bound process beside the test on
    # this 2-core machine (the gateway waiting for a core, not for remote). The bound:
    # a period and READ_MARGIN.
    period = 1 / next(n["expected_hz"] for n in gw.status()["nodes"] if n["node"] == 76)
    assert max(gaps) <= period + READ_MARGIN, (
        f"good's records stalled {max(gaps):.3f} s (its period {period:.3f} s)")

    def stations() -> dict[str, str]:
        return {s["name"]: s["state"] for s in gw.status()["stations"]}
    assert stations()["good"] == "up"
    runs: list[Ran] = []

    def shows_opening() -> Ran | None:
        ran = gx2ctl("--config", str(gw.path), "status", "--timeout", "3")
        runs.append(ran)
        assert ran.status in (0, 1), ran  # (3: the gateway did not answer)
        return ran if "-- remote (opening" in ran.stdout else None
    shows_opening_text = wait_for(shows_opening, 20, "status to show remote opening")
    assert "-- good (up" in shows_opening_text.stdout, shows_opening_text.stdout

    def json_opening() -> bool:
        ran = gx2ctl("--config", str(gw.path), "--json", "status", "--timeout", "3")
        assert ran.status in (0, 1), ran
        states = {s["name"]: s["state"] for s in json.loads(ran.stdout)["stations"]}
        return states == {"good": "up", "remote": "opening"}
    wait_for(json_opening, 20, "status --json to show remote opening")

    wait_for(lambda: stations()["remote"] == "opening", 10, "remote's open to hang again")
    status, seconds = gw.terminate()
    assert status == 0 and seconds < EXIT + STARVED, (status, seconds, gw.log())
    assert "stopped" in gw.log()


def test_shutdown_does_not_wait_for_an_open_that_hangs(gateway, hanging_port):
    """SIGTERM while the one station's connect hangs: the thread stuck in it is
    abandoned, not joined, and the gateway exits 0 within the promise."""
    gw = gateway(f"socket://127.0.0.1:{hanging_port}", [{"address": 77}], wait=False)
    wait_for(lambda: (r := gw.control.try_call("status", 0.5)) and r["ok"]
             and r["result"]["link"]["state"] == "opening", 20, "the link opening")
    status, seconds = gw.terminate()
    assert status == 0 and seconds < EXIT + STARVED, (status, seconds, gw.log())


HOLDER = """
import sys, serial
port = serial.Serial(sys.argv[1], exclusive=True)
print("held", flush=True)
sys.stdin.read()
"""


def test_a_port_another_process_holds_is_said_plainly(gateway):
    """A pty another process holds with pyserial's exclusive lock (as a second gateway
    would): status, gx2ctl status and the log say so in words, not pyserial's text."""
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    os.close(slave)
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, path], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        gw = gateway(path, [{"address": 76}], wait=False)
        plain = "port held by another process (another gateway?)"
        link = wait_for(lambda: (r := gw.control.try_call("status", 0.5)) and r["ok"]
                        and r["result"]["link"]["error"] and r["result"]["link"], 20,
                        "status to say why the link is down")
        assert link["error"] == plain and link["state"] in ("down", "opening"), link
        ran = gx2ctl("--config", str(gw.path), "status")
        assert ran.status == 0 and f"({plain})" in ran.stdout, ran
        assert f"cannot be opened: {plain}; retrying" in gw.log()
        assert "Errno" not in gw.log() and "exclusively lock" not in gw.log()
    finally:
        holder.kill()
        holder.wait()
        os.close(master)
