"""The gateway's health folded with what it owns (gateway/daemon/owned.py, folded in by
Health): a base station whose link is not up, or an MQTT output that cannot reach its
broker, makes the gateway ERROR, with the reason, whatever its own verdict (issue 43);
each change of that verdict is logged, as the gateway's own were (issue 43 review: the
folded ERROR was never logged)."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from gateway.daemon.config import HealthConfig
from gateway.daemon.health import Health
from gateway.daemon.owned import owned_reasons

OK = {"health": "OK", "reasons": []}
OVERFLOWED = "recording dropped 3 messages in 1 s: its queue was full (the disk does not keep up)"


class FakeRecorder:
    """What the gateway's health reads of its recorder."""

    def __init__(self, overflowed: int = 0) -> None:
        self.overflowed = overflowed
        self.failure = ""


def station(name: str, state: str = "up", error: str | None = None) -> dict:
    return {"name": name, "state": state, "error": error, "port": f"/dev/{name}"}


def folded(stations: Sequence[Mapping[str, Any]], outputs: Mapping[str, Any],
           overflowed: int = 0) -> dict[str, Any]:
    """The gateway's status map: its own verdict (WARN with ``overflowed``) with what
    it owns folded in."""
    recorder = FakeRecorder()
    health = Health([], HealthConfig(), recorder=recorder,
                    owned=lambda: owned_reasons(stations, outputs))
    health.sample(0.0)
    recorder.overflowed = overflowed
    return health.gateway_status(1.0)


def test_all_well_is_the_gateways_own_verdict() -> None:
    up = [station("station1")]
    assert folded(up, {"mqtt": None, "recording": None}) == OK
    assert folded(up, {"mqtt": {"connected": True, "error": None}}, 3) == {
        "health": "WARN", "reasons": [OVERFLOWED]}
    # (not connected yet, nothing refused: no reason to say)
    assert folded(up, {"mqtt": {"connected": False, "error": None}}) == OK


def test_a_station_down_is_an_error_of_the_gateway_with_why() -> None:
    down = [station("station1", "down", "could not open port /dev/x: No such file")]
    assert folded(down, {}) == {
        "health": "ERROR",
        "reasons": ["base station not up: /dev/station1: could not open port /dev/x: "
                    "No such file"]}
    several = [station("ch11"), station("ch15", "opening")]
    assert folded(several, {}, 3) == {
        "health": "ERROR", "reasons": ["base station ch15 opening", OVERFLOWED]}


def test_an_mqtt_broker_away_is_an_error_of_the_gateway_with_why() -> None:
    away = {"mqtt": {"connected": False,
                     "error": "cannot connect to 127.0.0.1:1: Connection refused"}}
    assert folded([station("station1")], away) == {
        "health": "ERROR",
        "reasons": ["mqtt: cannot connect to 127.0.0.1:1: Connection refused"]}


def test_each_change_of_the_folded_verdict_is_logged_once(caplog) -> None:
    """A station down, then the broker away too, then both back: the gateway's verdict
    changes twice (OK -> ERROR -> OK), each logged once with why; its reasons changing
    within ERROR are no change of level."""
    caplog.set_level(logging.INFO, "gx2.health")
    stations = [station("station1")]
    outputs: dict[str, Any] = {"mqtt": {"connected": True, "error": None}}
    health = Health([], HealthConfig(), owned=lambda: owned_reasons(stations, outputs))
    health.sample(1.0)
    stations[0] = station("station1", "down", "no such device (not plugged in?)")
    health.sample(2.0)
    outputs["mqtt"] = {"connected": False, "error": "cannot connect to b:1883: refused"}
    health.sample(3.0)
    stations[0] = station("station1")
    outputs["mqtt"] = {"connected": True, "error": None}
    health.sample(4.0)
    said = [(r.levelname, r.message) for r in caplog.records]
    assert said == [
        ("WARNING", "gateway health OK -> ERROR: base station not up: /dev/station1: "
                    "no such device (not plugged in?)"),
        ("INFO", "gateway health ERROR -> OK")], said
