"""Replay of a subscriber's recording (``gx2ctl record``: published messages, no
``serial`` channel): a gateway playing it publishes the file's messages again, as
recorded and in its order (a record as the gateway published it: its NaN, which the
file holds as null), past a record no frame can be made of; a recording with nothing to
play is refused in one line."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

from aspp.orientation import euler_from_matrix, matrix_from_euler, quaternion_from_matrix
from gateway.recording.writer import RecordingWriter
from gateway.sim.node import NodeSettings
from tests.helpers.gateway import is_nan
from tests.helpers.processes import Running, gx2ctl, script
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}, {"address": 77, "stream": "euler"}]
STATUS = "gx2/gateway/status"


def in_file(path: Path) -> list[tuple[str, dict]]:
    """(topic, payload) of each message in the file, in its order, read by the ``mcap``
    package (never our reader)."""
    from mcap.reader import make_reader
    with path.open("rb") as stream:
        return [(channel.topic, json.loads(message.data))
                for _, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False)]


def test_a_gx2ctl_recording_replays_by_publishing_its_messages_again(
        simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    live = gateway(sim.path, NODES)
    live.wait_streaming(76, 77)
    target = tmp_path / "capture.mcap"
    record = Running("gx2ctl", "--control", live.control_endpoint, "record", str(target),
                     "--seconds", "2")
    wait_for(target.exists, 10, "gx2ctl record to hear the gateway")
    marked = gx2ctl("--control", live.control_endpoint, "mark", "77", "a knock")
    assert marked.status == 0, marked
    assert record.finish(15) == 0, record.stderr
    recorded = in_file(target)
    expected = [(t, p) for t, p in recorded if t != STATUS]
    assert {t for t, _ in expected} == {"gx2/76/accel_angrate", "gx2/77/euler",
                                        "gx2/gateway/mark"}
    assert len(expected) > 300

    replay = gateway(f"replay://{target}?exit=true&speed=0&delay=2", NODES[:1], wait=False)
    sub = replay.subscribe("gx2/")
    # while it waits to play: a mark is refused (exit 1), as is any op on a node
    refused = gx2ctl("--control", replay.control_endpoint, "--timeout", "20", "mark",
                     "too late")
    assert refused.status == 1 and "replaying a recording" in refused.stderr, refused
    assert len(refused.stderr.splitlines()) == 1, refused
    wait_for(lambda: replay.proc.poll() is not None, 30, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    sub.drain_until_quiet()
    played = [(t, p) for t, p in sub.messages if t != STATUS]
    # the same messages, topics and payloads, in the same order; the recorded
    # gateway's status is not published again (the replaying gateway has its own)
    assert played == expected
    assert any(t == STATUS for t, _ in sub.messages)
    assert f"{len(expected)} messages published again" in replay.log()


def test_a_recording_with_nothing_to_play_is_refused_in_one_line(tmp_path):
    path = tmp_path / "status-only.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        writer.message(STATUS, {"gateway": {"time": 1.7e9}, "nodes": []})
        writer.message("other/topic", {"host_time": 1.7e9 + 1})
        writer.finish()
    config = tmp_path / "nodes.yaml"
    config.write_text(f"base_station: {{port: 'replay://{path}?exit=true'}}\n"
                      "nodes: [{address: 76}]\n")
    for check in (["--check"], []):
        ran = subprocess.run([script("gx2-gateway"), "--config", str(config), *check],
                             capture_output=True, text=True, timeout=30)
        assert ran.returncode == 2, (check, ran)
        lines = ran.stderr.strip().splitlines()
        assert len(lines) == 1 and "nothing to replay" in lines[0], ran.stderr
        assert str(path) in lines[0]


def orientation_file(path: Path, count: int, nan_at: int) -> list[dict]:
    """``count`` orientation records of node 77 as the gateway publishes them (a turning
    matrix, its angles and quaternion), record ``nan_at`` a NaN matrix (a node's
    orientation it could not compute), written by the project's own writer (NaN as
    null, as the recorder writes it)."""
    payloads = []
    for seq in range(1, count + 1):
        matrix = matrix_from_euler(0.2, -0.1, seq / 100)
        if seq == nan_at:
            matrix = ((math.nan,) * 3,) * 3
        roll, pitch, yaw = euler_from_matrix(matrix)
        payloads.append({
            "orientation": [list(row) for row in matrix], "timer": seq * 1966, "node": 77,
            "record": "orientation", "command": 0xC5, "seq": seq,
            "host_time": 1.7e9 + seq / 100 + 0.004, "lqi": 200, "rssi": -45,
            "station": "station1", "roll": roll, "pitch": pitch, "yaw": yaw,
            "quaternion": list(quaternion_from_matrix(matrix)), "device_time": seq / 100,
            "time": 1.7e9 + seq / 100})
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for payload in payloads:
            writer.message("gx2/77/orientation", payload)
        writer.finish()
    return payloads


def test_a_replay_goes_on_past_a_nan_matrix_and_publishes_every_record(
        gateway, tmp_path: Path) -> None:
    """A recording holds a NaN quaternion as four nulls: replayed with an output that
    makes frames (record:), every record is published again, the NaN one with its NaN
    (as the gateway published it), and the frames of the others are made; the replay
    no longer stops for good there (it published 101 of 300)."""
    path = tmp_path / "turning.mcap"
    written = orientation_file(path, 300, nan_at=100)
    again = tmp_path / "again"
    replay = gateway(f"replay://{path}?exit=true&speed=0&delay=2", [{"address": 77}],
                     wait=False, record={"directory": str(again)})
    sub = replay.subscribe("gx2/77/")
    wait_for(lambda: replay.proc.poll() is not None, 30, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    # (read until all are in, not for 0.3 s: beside the suite's other processes 166 had
    # been read by then)
    sub.until(lambda got: len(got) >= 300, 10, "the 300 records")
    sub.drain(0.1)
    assert [p["seq"] for _, p in sub.messages] == list(range(1, 301))
    nan = sub.messages[99][1]
    assert all(is_nan(v) for v in (*nan["quaternion"], nan["roll"], *nan["orientation"][0]))
    assert sub.messages[100][1]["quaternion"] == written[100]["quaternion"]
    assert "300 messages published again" in replay.log()
    assert "Traceback" not in replay.log() and "a bug" not in replay.log()
    (recorded,) = again.glob("*.mcap")
    topics = [topic for topic, _ in in_file(recorded)]
    assert topics.count("gx2/77/orientation") == 300
    assert topics.count("gx2/77/frame") == 299  # (none from the NaN matrix)
