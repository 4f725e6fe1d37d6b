"""systemd integration through a real notify socket, as the service manager provides it:
READY only once the port is open and the sockets are bound, WATCHDOG while the reader
or the reopen loop is alive, STOPPING on shutdown."""

from __future__ import annotations

import configparser
import os
import socket
import time
from pathlib import Path

from gateway.daemon.sd_notify import Notifier
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.processes import EXIT, STARVED
from tests.helpers.waiting import wait_for

ROOT = Path(__file__).parents[2]


class NotifySocket:
    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.setblocking(False)
        self.received: list[tuple[float, set[str]]] = []

    def collect(self) -> list[set[str]]:
        while True:
            try:
                data = self.sock.recv(4096)
            except BlockingIOError:
                return [lines for _, lines in self.received]
            self.received.append((time.monotonic(), set(data.decode().split("\n"))))

    def count(self, line: str) -> int:
        return sum(line in lines for lines in self.collect())


def test_ready_watchdog_and_stopping(gateway, tmp_path):
    notify = NotifySocket(str(tmp_path / "notify"))
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "300000"}
    link = tmp_path / "gx2"  # the base station is not plugged in yet
    gw = gateway(str(link), [{"address": 76, "stream": "euler"}], wait=False, env=env)
    wait_for(lambda: gw.control.try_call("status", timeout=0.5), 20, "the control socket")
    # (not up: "opening" while an attempt to open it is in flight, "down" between them)
    assert gw.status()["link"]["state"] in ("down", "opening")
    wait_for(lambda: notify.count("WATCHDOG=1") >= 2, 5, "watchdog pings while reopening")
    assert notify.count("READY=1") == 0, "READY before the port was open"

    sim = Simulator([NodeSettings(76)], link=link).start()  # plugged in
    try:
        wait_for(lambda: notify.count("READY=1") == 1, 10, "READY=1")
        assert gw.status()["link"]["state"] == "up"
        pings = notify.count("WATCHDOG=1")
        wait_for(lambda: notify.count("WATCHDOG=1") >= pings + 3, 5, "pings while reading")
        status, seconds = gw.terminate()
        assert status == 0 and seconds < EXIT + STARVED
        assert notify.count("STOPPING=1") == 1
        assert notify.count("READY=1") == 1
    finally:
        sim.stop()


def test_notifier_is_silent_outside_systemd_and_speaks_to_abstract_sockets():
    assert Notifier({}).enabled is False and Notifier({}).ready("x") is False
    name = f"gx2-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind("\0" + name)
        notifier = Notifier({"NOTIFY_SOCKET": "@" + name, "WATCHDOG_USEC": "2000000"})
        assert notifier.watchdog_interval == 1.0
        assert notifier.ready("up")
        assert server.recv(100) == b"READY=1\nSTATUS=up"
    other = Notifier({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "5", "WATCHDOG_PID": "1"})
    assert other.watchdog_interval is None  # the watchdog is some other process's
    assert Notifier({"NOTIFY_SOCKET": "/nonexistent/socket"}).ready("x") is False


def test_service_unit_hardening():
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # keys are case-sensitive
    text = (ROOT / "deploy" / "gx2-gateway.service").read_text()
    unit.read_string(text)
    service = unit["Service"]
    assert service["Type"] == "notify"
    assert service["Restart"] == "always"
    assert int(service["WatchdogSec"].rstrip("s")) > 0
    assert service["User"] and service["SupplementaryGroups"] == "dialout"
    assert service["ProtectSystem"] == "strict" and service["NoNewPrivileges"] == "yes"
    assert service["CapabilityBoundingSet"] == "" and service["RuntimeDirectory"]
    assert "DeviceAllow=char-ttyUSB rw" in text and "DeviceAllow=char-ttyACM rw" in text
    assert "gx2-gateway --config /etc/gx2-gateway/" in service["ExecStart"]
    # systemctl reload is the gateway's SIGHUP: its nodes re-read (tests/e2e/test_reload.py)
    assert service["ExecReload"] == "/bin/kill -HUP $MAINPID"


def test_udev_rule():
    rules = (ROOT / "deploy" / "99-gx2-basestation.rules").read_text()
    lines = [line for line in rules.splitlines() if line and not line.startswith("#")]
    assert any('SYMLINK+="gx2-basestation"' in line for line in lines)
    assert any('ENV{ID_MM_DEVICE_IGNORE}="1"' in line for line in lines)
    assert any('ATTR{latency_timer}="1"' in line for line in lines)
