"""A recording of several base stations, replayed by several stations, is read (and
decompressed) once: each station still plays its own reads, in order, and nothing
else; a station that stops playing leaves the reading to the others."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from gateway.daemon.station.replay import ReplayLink
from gateway.daemon.station.replayread import ReplayReader
from gateway.daemon.station.replayurl import Replay
from gateway.recording import reader as recording_reader
from gateway.recording.files import serial_channels
from gateway.recording.writer import RecordingWriter

STATIONS = ("north", "south")
READS = 600  # (past the reader's queue: the reading waits for the slower station)


def two_stations_recorded(path: Path) -> None:
    metadata = {"stations": json.dumps([{"name": name} for name in STATIONS])}
    with path.open("wb") as output:
        writer = RecordingWriter(output, metadata)
        for index in range(READS):
            for name in STATIONS:
                writer.serial(f"{name} {index};".encode(), 1.7e9 + index / 100,
                              100 + index / 100, topic=serial_channels(name)[0])
        writer.finish()


def play(path: Path, stations: tuple[str, ...], leaving: str | None = None,
         ) -> tuple[dict[str, list[bytes]], int]:
    """What each station played, and how many times a file was walked."""
    played: dict[str, list[bytes]] = {name: [] for name in stations}

    async def run() -> None:
        replay = Replay((path,), speed=0, delay=0)
        source = ReplayReader(replay.files)
        ended = {name: asyncio.Event() for name in stations}
        links = {}
        for name in stations:
            def on_data(data: bytes, host: float, mono: float, name: str = name) -> None:
                played[name].append(data)
                if name == leaving and len(played[name]) == 10:
                    links[name].close()
                    ended[name].set()
            links[name] = ReplayLink(replay, on_data, lambda up: None,
                                     ended[name].set, lambda topic, payload: True,
                                     station=name, source=source)
        for link in links.values():
            link.start()
        await asyncio.wait_for(asyncio.gather(*(e.wait() for e in ended.values())), 30)
    asyncio.run(run())
    return played, walked[0]


walked = [0]


@pytest.fixture(autouse=True)
def count_walks(monkeypatch: pytest.MonkeyPatch) -> None:
    walked[0] = 0
    real = recording_reader._Walk.__init__

    def counted(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        walked[0] += 1
        real(self, *args, **kwargs)
    monkeypatch.setattr(recording_reader._Walk, "__init__", counted)


def test_two_stations_replaying_one_recording_read_it_once(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    two_stations_recorded(path)
    played, walks = play(path, STATIONS)
    assert walks == 1
    for name in STATIONS:
        assert played[name] == [f"{name} {i};".encode() for i in range(READS)]


def test_a_station_that_stops_playing_leaves_the_others_the_whole_recording(
        tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    two_stations_recorded(path)
    played, walks = play(path, STATIONS, leaving="north")
    assert walks == 1 and len(played["north"]) == 10
    assert played["south"] == [f"south {i};".encode() for i in range(READS)]


def test_a_station_whose_play_fails_leaves_the_reading_and_ends(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """North's play dies of an error (a bug: here its reader raises): it still leaves
    the reading, so south plays the whole recording, and it still ends (partial, said
    in a line), so a replay with exit=true exits."""
    path = tmp_path / "two.mcap"
    two_stations_recorded(path)
    played: dict[str, int] = {name: 0 for name in STATIONS}

    async def run() -> dict[str, ReplayLink]:
        replay = Replay((path,), speed=0, delay=0)
        source = ReplayReader(replay.files)
        ended = {name: asyncio.Event() for name in STATIONS}
        links = {}
        for name in STATIONS:
            def on_data(data: bytes, host: float, mono: float, name: str = name) -> None:
                played[name] += 1
                if name == "north" and played[name] == 10:
                    raise RuntimeError("a reader's bug")
            links[name] = ReplayLink(replay, on_data, lambda up: None, ended[name].set,
                                     lambda topic, payload: True, station=name,
                                     source=source)
        for link in links.values():
            link.start()
        await asyncio.wait_for(asyncio.gather(*(e.wait() for e in ended.values())), 5)
        return links
    links = asyncio.run(run())
    assert played == {"north": 10, "south": READS}
    north = links["north"]
    assert north.finished and north.partial
    assert "RuntimeError: a reader's bug" in north.last_error
    assert [r.message for r in caplog.records if "a reader's bug" in r.message] == [
        "replay: the replay stopped: RuntimeError: a reader's bug (a bug: please report it)"]
