"""The gateway's health folded with what it owns (gateway/daemon/owned.py): a base
station whose link is not up, or an MQTT output that cannot reach its broker, makes the
gateway ERROR, with the reason, whatever its own verdict (issue 43)."""

from __future__ import annotations

from gateway.daemon.owned import fold

OK = {"health": "OK", "reasons": []}
WARN = {"health": "WARN", "reasons": ["recording dropped 3 messages in 60 s"]}


def station(name: str, state: str = "up", error: str | None = None) -> dict:
    return {"name": name, "state": state, "error": error, "port": f"/dev/{name}"}


def test_all_well_is_the_gateways_own_verdict() -> None:
    up = [station("station1")]
    assert fold(OK, up, {"mqtt": None, "recording": None}) == OK
    assert fold(WARN, up, {"mqtt": {"connected": True, "error": None}}) == WARN
    # (not connected yet, nothing refused: no reason to say)
    assert fold(OK, up, {"mqtt": {"connected": False, "error": None}}) == OK


def test_a_station_down_is_an_error_of_the_gateway_with_why() -> None:
    down = [station("station1", "down", "could not open port /dev/x: No such file")]
    assert fold(OK, down, {}) == {
        "health": "ERROR",
        "reasons": ["base station not up: /dev/station1: could not open port /dev/x: "
                    "No such file"]}
    several = [station("ch11"), station("ch15", "opening")]
    assert fold(WARN, several, {}) == {
        "health": "ERROR", "reasons": ["base station ch15 opening", *WARN["reasons"]]}


def test_an_mqtt_broker_away_is_an_error_of_the_gateway_with_why() -> None:
    away = {"mqtt": {"connected": False,
                     "error": "cannot connect to 127.0.0.1:1: Connection refused"}}
    assert fold(OK, [station("station1")], away) == {
        "health": "ERROR",
        "reasons": ["mqtt: cannot connect to 127.0.0.1:1: Connection refused"]}
