"""Recordings of a known content, written through the recording writer a second at a
time (a chunk a second, as the recorder flushes): nodes 11 and 12 at RATE Hz, node 13's
euler at a fifth of it, the status each second, and the marks MARKS."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.writer import Writer

from gateway.recording.files import MARK
from gateway.recording.writer import RecordingWriter

T0 = 1_795_000_000.0
FILE_SECONDS = 20
RATE = 25
MARKS = [(5.0, "start"), (12.0, "stop"), (25.0, "start"), (45.0, "stop"), (50.5, "event")]
"""(seconds after T0, text): two trials, the second across two files."""


def _records(writer: RecordingWriter, second: int) -> None:
    for i in range(RATE):
        at = T0 + second + i / RATE
        for node in (11, 12):
            writer.message(f"gx2/{node}/accel_angrate", {
                "node": node, "record": "accel_angrate", "command": 0xC2,
                "seq": second * RATE + i, "host_time": at, "time": at - 0.002,
                "device_time": second + i / RATE, "timer": (second * RATE + i) * 7864,
                "lqi": 200, "rssi": -50, "accel": [0.0, 0.1, -1.0], "ang_rate": [0.1, 0.2, i]})
        if i % 5 == 0:
            writer.message("gx2/13/euler", {
                "node": 13, "record": "euler", "command": 0xCE, "seq": second * 5 + i // 5,
                "host_time": at + 0.001, "roll": 0.1, "pitch": 0.2, "yaw": 0.3})


def make_file(path: Path, first: int, seconds: int, finish: bool = True) -> Path:
    """Seconds ``first`` to ``first + seconds`` after T0 (a chunk each), with the marks
    that fall in them; finished (summary and index) or left as a killed writer leaves it."""
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for second in range(first, first + seconds):
            writer.message("gx2/gateway/status", {"gateway": {"time": T0 + second},
                                                  "nodes": []})
            for at, text in MARKS:
                if second <= at < second + 1:
                    writer.message(MARK, {"time": T0 + at, "host_time": T0 + at,
                                          "nodes": [], "text": text})
            _records(writer, second)
            writer.flush()
        if finish:
            writer.finish()
    return path


def foreign_file(path: Path, entries: list[tuple[str, dict]], **options: Any) -> Path:
    """A recording written by another program (the mcap package's writer), each message
    logged at its ``host_time``: its other times as it gave them; ``options``, the
    writer's (``use_statistics=False`` ...)."""
    with path.open("wb") as stream:
        writer = Writer(stream, **options)
        writer.start(profile="", library="another")
        channels: dict[str, int] = {}
        for topic, payload in entries:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "json", schema_id=0)
            at = round(payload["host_time"] * 1e9)
            writer.add_message(channels[topic], at, json.dumps(payload).encode(), at)
        writer.finish()
    return path


def hourly_files(tmp_path: Path) -> Path:
    """Three finished hourly-like files of FILE_SECONDS each, in one folder, named as the
    recorder names them."""
    folder = tmp_path / "recordings"
    folder.mkdir()
    for k in range(3):
        make_file(folder / f"gx2-2026112{k}T000000.000Z.mcap", k * FILE_SECONDS, FILE_SECONDS)
    return folder
