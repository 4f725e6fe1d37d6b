"""Stations replaying one recording at different paces are not tied together: each
plays at its own, and the gateway exits once every one is done when any asked to."""

from __future__ import annotations

import time

from tests.daemon.station.test_replayread import two_stations_recorded
from tests.helpers.waiting import wait_for

SOUTH_DELAY = 4.0


def test_a_station_of_another_delay_neither_holds_another_nor_keeps_the_gateway(
        gateway, tmp_path):
    path = tmp_path / "two.mcap"
    two_stations_recorded(path)
    url = f"replay://{path}?speed=0"
    started = time.monotonic()
    gw = gateway(None, [], base_stations=[
        {"name": "north", "port": f"{url}&delay=0", "nodes": [{"address": 76}]},
        {"name": "south", "port": f"{url}&delay={SOUTH_DELAY:g}&exit=true",
         "nodes": [{"address": 77}]}])
    # north plays at once, never waiting for south's delay to pass
    wait_for(lambda: gw.log().count("replay finished") >= 1, SOUTH_DELAY - 1,
             "north's replay to finish before south's starts")
    assert time.monotonic() - started < SOUTH_DELAY, gw.log()
    assert gw.log().count("replay finished") == 1, gw.log()
    # south (exit=true) ends last of the two, as it must: the gateway exits
    wait_for(lambda: gw.proc.poll() is not None, SOUTH_DELAY + 5,
             "the gateway to exit once both replays are done")
    assert gw.proc.returncode == 0, gw.log()
    assert gw.log().count("replay finished") == 2, gw.log()


def test_the_gateway_exits_when_the_station_that_asked_ends_first(gateway, tmp_path):
    path = tmp_path / "two.mcap"
    two_stations_recorded(path)
    url = f"replay://{path}?speed=0"
    gw = gateway(None, [], base_stations=[
        {"name": "north", "port": f"{url}&delay=0&exit=true", "nodes": [{"address": 76}]},
        {"name": "south", "port": f"{url}&delay=2", "nodes": [{"address": 77}]}])
    wait_for(lambda: gw.proc.poll() is not None, 10,
             "the gateway to exit once both replays are done (north asked)")
    assert gw.proc.returncode == 0, gw.log()
    assert gw.log().count("replay finished") == 2, gw.log()
