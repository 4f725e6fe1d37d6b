"""A node's orientation as Foxglove draws it, through the installed gateway on gx2-sim:
what a Foxglove client receives on gx2/<node>/frame holds to Foxglove's FrameTransform
(its JSON Schema as Foxglove publishes it, written out here apart from the gateway's),
at the sample's instant, turned as the record's quaternion; the recording's frame
channel read back with the mcap package's reader; ZeroMQ subscribers' topics as they
were; the records' angles and quaternion in gx2ctl export's tables; a replay making the
frames afresh, once each."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.helpers.ports import free_port
from tests.helpers.processes import gx2ctl
from tests.helpers.schemas import validate
from tests.helpers.viewer import Viewer
from tests.helpers.waiting import wait_for

NUMBER = {"type": "number"}
FOXGLOVE_FRAME_TRANSFORM = {
    # foxglove.FrameTransform in its JSON encoding (docs.foxglove.dev, message schemas):
    # what Foxglove's 3D panel reads, every key required here, nothing else allowed
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "additionalProperties": False,
                      "required": ["sec", "nsec"],
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0,
                                              "maximum": 999_999_999}}},
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": {"type": "object", "additionalProperties": False,
                        "required": ["x", "y", "z"],
                        "properties": {"x": NUMBER, "y": NUMBER, "z": NUMBER}},
        "rotation": {"type": "object", "additionalProperties": False,
                     "required": ["x", "y", "z", "w"],
                     "properties": {"x": NUMBER, "y": NUMBER, "z": NUMBER, "w": NUMBER}},
    },
    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation",
                 "rotation"],
    "additionalProperties": False,
}
NODES = [{"address": 76, "name": "left-wing", "stream": "accel_angrate_orientation"},
         {"address": 77, "stream": "euler"}]
FRAMES = {"gx2/76/frame": "left-wing", "gx2/77/frame": "gx2-77"}
SWING = Motion(roll=0.3, pitch=-0.2, yaw_rate=0.5, swing=0.4)


def stamp(frame: dict[str, Any]) -> int:
    return frame["timestamp"]["sec"] * 1_000_000_000 + frame["timestamp"]["nsec"]


def turned_as_the_record(frame: dict[str, Any], record: dict[str, Any]) -> None:
    w, x, y, z = record["quaternion"]
    assert frame["rotation"] == pytest.approx({"x": x, "y": y, "z": z, "w": w}, abs=1e-12)


@pytest.fixture
def running(simulator, gateway, tmp_path: Path):
    sim = simulator(NodeSettings(76, stream="accel_angrate_orientation", motion=SWING),
                    NodeSettings(77, stream="euler", motion=SWING))
    gw = gateway(sim.path, NODES, live={"endpoint": f"127.0.0.1:{free_port()}"},
                 record={"directory": str(tmp_path / "rec")})
    gw.wait_streaming(76, 77)
    return gw


def test_a_foxglove_client_gets_each_nodes_frame_and_the_recording_keeps_it(
        running, gateway, tmp_path: Path) -> None:
    gw = running
    sub = gw.subscribe("gx2/")
    viewer = Viewer(f"ws://{gw.config['live']['endpoint']}")
    try:
        viewer.until(lambda v: set(FRAMES) <= set(v.topics()), 10, "the frame channels")
        channels = {c["topic"]: c for c in viewer.channels.values()}
        for topic in FRAMES:
            assert channels[topic]["schemaName"] == "foxglove.FrameTransform"
            assert (channels[topic]["encoding"], channels[topic]["schemaEncoding"]) == (
                "json", "jsonschema")
        record_topic = "gx2/76/accel_angrate_orientation"
        viewer.subscribe(*(viewer.topics()[t] for t in (*FRAMES, record_topic)))
        viewer.until(lambda v: sum(m.topic == "gx2/76/frame" for m in v.messages) > 150
                     and any(m.topic == "gx2/77/frame" for m in v.messages), 10,
                     "frames of both nodes")
        sub.drain(0.3)
    finally:
        viewer.close()
    # ZeroMQ's topics are the records', as before: no frame, and the record's new fields
    assert {t for t, _ in sub.messages if t.startswith("gx2/7")} == {
        record_topic, "gx2/77/euler"}
    assert all(-3.2 < p["roll"] < 3.2 and len(p["quaternion"]) == 4
               for t, p in sub.messages if t == record_topic)
    assert {c["topic"] for c in viewer.channels.values()} & {"gx2/gateway/frame"} == set()

    records = {m.log_time: m.payload for m in viewer.messages if m.topic == record_topic}
    matched = 0
    for message in viewer.messages:
        if message.topic not in FRAMES:
            continue
        frame = message.payload
        validate(frame, FOXGLOVE_FRAME_TRANSFORM)
        validate(frame, json.loads(channels[message.topic]["schema"]))
        assert frame["child_frame_id"] == FRAMES[message.topic]
        assert frame["parent_frame_id"] == "world"
        assert message.log_time == stamp(frame)  # at the sample's instant
        if message.topic == "gx2/76/frame" and message.log_time in records:
            turned_as_the_record(frame, records[message.log_time])
            matched += 1
    assert matched > 100, matched

    status, _ = gw.terminate()
    assert status == 0, gw.log()
    (path,) = (tmp_path / "rec").glob("*.mcap")
    recorded: dict[str, list[tuple[Any, Any, Any]]] = {}
    with path.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages():
            recorded.setdefault(channel.topic, []).append((schema, channel, message))
    samples = {round(json.loads(m.data)["time"] * 1e9): json.loads(m.data)
               for _, _, m in recorded[record_topic]}
    for topic in FRAMES:
        frames = recorded[topic]
        schema, channel, _ = frames[0]
        assert (schema.name, schema.encoding, channel.message_encoding) == (
            "foxglove.FrameTransform", "jsonschema", "json")
        for _, _, message in frames:
            frame = json.loads(message.data)
            validate(frame, FOXGLOVE_FRAME_TRANSFORM)
            assert message.publish_time == stamp(frame)
            assert frame["child_frame_id"] == FRAMES[topic]
    # one frame a record, each turned as its record at its instant
    frames76 = [json.loads(m.data) for _, _, m in recorded["gx2/76/frame"]]
    assert len(frames76) == len(samples) > 150
    for frame in frames76:
        turned_as_the_record(frame, samples[stamp(frame)])
    assert len(recorded["gx2/77/frame"]) == len(recorded["gx2/77/euler"])

    # export: the record's angles and quaternion as columns, and no table of frames
    out = tmp_path / "out"
    ran = gx2ctl("export", str(path), "--out", str(out))
    assert ran.status == 0, ran.stderr
    tables = {p.name for p in out.iterdir()}
    assert {"76_accel_angrate_orientation.csv", "77_euler.csv"} <= tables
    assert not [name for name in tables if "frame" in name], tables
    with (out / "76_accel_angrate_orientation.csv").open() as table:
        rows = list(csv.DictReader(table))
    assert {"roll", "pitch", "yaw", "quaternion_w", "quaternion_x", "quaternion_y",
            "quaternion_z"} <= set(rows[0])
    assert float(rows[0]["quaternion_w"]) == pytest.approx(
        samples[min(samples)]["quaternion"][0], abs=1e-9)

    # replayed, the frames are made afresh from the records, once each (the recorded
    # frame channels are not played again on top of them)
    again = tmp_path / "again"
    replay = gateway(f"replay://{path}?exit=true&speed=0", NODES, wait=False,
                     record={"directory": str(again)})
    wait_for(lambda: replay.proc.poll() is not None, 60, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    (replayed,) = again.glob("*.mcap")
    with replayed.open("rb") as stream:
        played = [(channel.topic, json.loads(message.data))
                  for _, channel, message in make_reader(stream).iter_messages()
                  if channel.message_encoding == "json"]
    for topic, record in (("gx2/76/frame", record_topic), ("gx2/77/frame", "gx2/77/euler")):
        frames = [p for t, p in played if t == topic]
        assert len(frames) == len([p for t, p in played if t == record]) == len(
            recorded[topic]), topic
        assert [f["rotation"] for f in frames] == [
            json.loads(m.data)["rotation"] for _, _, m in recorded[topic]], topic
