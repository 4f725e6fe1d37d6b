"""Which base station replays what: a file of several stations' reads is played by each
station under its own name, and a station it holds nothing of is refused in one line
naming the stations it holds; a file of one station's reads is played by a station of
any name."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import yaml

from gateway.common.jsontext import strict
from tests.e2e.test_recording import payloads, record_simulator, recorded
from tests.e2e.test_stations import two_stations
from tests.helpers.processes import script
from tests.helpers.waiting import wait_for

PLAY = "?speed=0&exit=true&delay=2"


def refused(tmp_path: Path, config: dict[str, Any]) -> list[str]:
    """The lines gx2-gateway says, with and without --check, refusing ``config``."""
    path = tmp_path / "refused.yaml"
    path.write_text(yaml.safe_dump(config))
    said = []
    for check in (["--check"], []):
        ran = subprocess.run([script("gx2-gateway"), "--config", str(path), *check],
                             capture_output=True, text=True, timeout=30)
        assert ran.returncode == 2, (check, ran)
        lines = ran.stderr.strip().splitlines()
        assert len(lines) == 1, ran.stderr
        said.append(lines[0])
    return said


def replayed(gateway, stations: list[dict[str, Any]]) -> dict[tuple[int, int], dict]:
    """What a gateway of ``stations`` publishes replaying (node, seq) -> payload; it
    exits 0 once done."""
    replay = gateway(None, [], base_stations=stations)
    sub = replay.subscribe("gx2/")
    wait_for(lambda: replay.proc.poll() is not None, 60, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    sub.drain_until_quiet()
    return {(p["node"], p["seq"]): strict(p) for t, p in sub.messages if t[4].isdigit()}


def same_but_station(played: dict, live: dict, station: dict[int, str]) -> None:
    assert played.keys() == live.keys()
    for key, payload in live.items():
        assert played[key] == {**payload, "station": station[key[0]]}, key


def test_a_several_station_recording_is_replayed_by_name_and_refused_to_others(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    _, _, gw = two_stations(simulator, gateway, record={"directory": str(directory)})
    gw.subscribe("gx2/").drain(2.0)
    assert gw.terminate()[0] == 0, gw.log()
    live = {key: payload for key, (_, payload) in payloads(recorded(directory)).items()}
    url = f"replay://{directory}{PLAY}"
    [file] = sorted(directory.glob("*.mcap"))

    # the one-station form, as docs/recording.md shows it: it has no name to give its
    # station (the default, station1, is not the user's), so the advice is the other form
    for line in refused(tmp_path, {"base_station": {"port": url},
                                   "nodes": [{"address": 76}]}):
        assert line.endswith(f"base_station.port: {file} holds the reads of base stations "
                             "north, south: replay it under base_stations:, each station "
                             "named as one of them (see docs/recording.md, Recording and "
                             "replay)"), line
    # a station of other names among several
    for line in refused(tmp_path, {"base_stations": [
            {"name": "north", "port": url, "nodes": [{"address": 76}]},
            {"name": "east", "port": url, "nodes": [{"address": 78}]}]}):
        assert "base_stations[1].port" in line and "north, south, none named 'east'" in line

    # one station, named as one of the recording's: that one's records, as recorded
    north = {key: payload for key, payload in live.items() if key[0] in (76, 77)}
    assert replayed(gateway, [{"name": "north", "port": url, "nodes": [
        {"address": 76}, {"address": 77}]}]) == north


def test_a_one_station_recording_is_replayed_by_a_station_of_any_name(
        simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    record_simulator(simulator, gateway, directory, 2.0)
    live = {key: payload for key, (_, payload) in payloads(recorded(directory)).items()}
    assert {payload["station"] for payload in live.values()} == {"station1"}
    url = f"replay://{directory}{PLAY}"
    # each of two stations plays the file, its own nodes' records
    played = replayed(gateway, [
        {"name": "west", "port": url, "nodes": [{"address": 76}]},
        {"name": "east", "port": url, "nodes": [{"address": 77}]}])
    same_but_station(played, live, {76: "west", 77: "east"})
