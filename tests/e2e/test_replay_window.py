"""replay:// with a window: the gateway plays only the messages logged in it (the files
it touches read by seeking), named as export names them; a window that cannot be taken
is the configuration's error, in one line."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.helpers.processes import script
from tests.helpers.recorded import T0, make_file
from tests.helpers.waiting import wait_for

NODES = [{"address": 11, "stream": "accel_angrate"}]
STATUS = "gx2/gateway/status"


def recorded(paths: list[Path], start: float, end: float) -> list[tuple[str, dict]]:
    """(topic, payload) of each message logged in [start, end], by the mcap package."""
    found = []
    for path in paths:
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(
                    starting_at=round(start * 1e9), ending_at=round(end * 1e9),
                    log_time_order=False):
                if channel.topic != STATUS:
                    found.append((channel.topic, json.loads(message.data)))
    return found


def test_a_replay_plays_the_trial_asked(gateway, tmp_path: Path) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    files = [make_file(folder / f"gx2-{k}.mcap", k * 20, 20) for k in range(3)]
    replay = gateway(f"replay://{folder}?between=start,stop&trial=2&exit=true&speed=0"
                     "&delay=2", NODES, wait=False)
    sub = replay.subscribe("gx2/")
    wait_for(lambda: replay.proc.poll() is not None, 30, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    sub.drain_until_quiet()
    played = [(t, p) for t, p in sub.messages if t != STATUS]
    # the second trial: from the mark "start" at 25 s to the mark "stop" at 45 s, both held
    assert played == recorded(files[1:], T0 + 25, T0 + 45)


def check(tmp_path: Path, query: str) -> subprocess.CompletedProcess[str]:
    """``gx2-gateway --check`` of a replay of a 3 s recording with ``query``."""
    path = make_file(tmp_path / "one.mcap", 0, 3)
    config = tmp_path / "nodes.yaml"
    config.write_text(f"base_station: {{port: 'replay://{path}?{query}'}}\n"
                      "nodes: [{address: 11}]\n")
    return subprocess.run([script("gx2-gateway"), "--config", str(config), "--check"],
                          capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("query, said", [
    ("from=nosuch", "from nosuch: no such mark"),  # the URL's key, not export's option
    ("from=1e300", "from 1e300: seconds from the recordings' start beyond"),
    ("from=-1e300", "from -1e300: seconds from the recordings' start beyond"),
    ("from=2&to=1", "to (2026-11-18T11:06:41.000Z) is not after from"),
    ("node=11", "a replay has no node/record keys: it plays the base station's serial"),
])
def test_a_window_a_replay_cannot_take_is_one_line(tmp_path: Path, query: str,
                                                   said: str) -> None:
    ran = check(tmp_path, query)
    assert ran.returncode == 2, ran
    lines = ran.stderr.strip().splitlines()
    assert len(lines) == 1 and said in lines[0], lines


@pytest.mark.parametrize("start", ["2026-11-18T12:06:41+01:00", "2026-11-18T11:06:41z"])
def test_a_replay_window_takes_a_zone_offset_and_lowercase_z(tmp_path: Path,
                                                             start: str) -> None:
    ran = check(tmp_path, f"from={start}")  # (+ unescaped, as a user writes it)
    assert ran.returncode == 0, ran.stderr
