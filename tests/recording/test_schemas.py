"""Every JSON channel of a recording carries its JSON Schema, and every message meets it:
the files read back by the ``mcap`` package's own reader and checked by the
``jsonschema`` package (never our code), written by the recording writer, by the real
gateway recording the simulator, and by ``gx2ctl record``."""

from __future__ import annotations

import json
import math
import signal
from collections import Counter
from pathlib import Path

from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from aspp.records import decode, encode
from gateway.common.jsontext import strict
from gateway.recording.writer import RecordingWriter
from gateway.sim.node import NodeSettings
from tests.helpers.processes import Running, gx2ctl
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"},
         {"address": 77, "stream": "accel_angrate_mag"}]  # an Inertia-Link: mag NaN
POLLED = ("temperatures", "accel_angrate_mag_orientation", "firmware_version")
STATUS, MARK = "gx2/gateway/status", "gx2/gateway/mark"


def schema_name(topic: str) -> str:
    """gx2/76/euler: gx2.euler; gx2/gateway/status: gx2.gateway.status; a node's frame,
    gx2/76/frame: Foxglove's own foxglove.FrameTransform."""
    _, where, what = topic.split("/")
    if where.isdecimal() and what == "frame":
        return "foxglove.FrameTransform"
    return f"gx2.{what}" if where.isdecimal() else f"gx2.{where}.{what}"


def checked(path: Path) -> Counter[str]:
    """Messages by topic of a finished file, after checking that each JSON channel has
    a jsonschema schema named for its topic and that each of its messages meets it;
    the serial channels (raw bytes) have none."""
    counts: Counter[str] = Counter()
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None, f"{path} was not finished"
        # one schema record a schema, however many channels share it
        names = [schema.name for schema in summary.schemas.values()]
        assert len(names) == len(set(names)), names
        validators: dict[int, Draft202012Validator] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            counts[channel.topic] += 1
            if channel.message_encoding != "json":
                assert channel.schema_id == 0 and schema is None, channel
                continue
            assert channel.schema_id != 0, f"{channel.topic} has no schema"
            assert schema.encoding == "jsonschema"
            assert schema.name == schema_name(channel.topic), (schema.name, channel.topic)
            validator = validators.get(schema.id)
            if validator is None:
                definition = json.loads(schema.data)
                Draft202012Validator.check_schema(definition)
                validator = validators[schema.id] = Draft202012Validator(definition)
            validator.validate(json.loads(message.data))
    return counts


def test_the_writer_gives_each_json_channel_its_schema_once_and_serial_none(tmp_path):
    nan = math.nan
    record = decode(encode("accel_angrate_mag", accel=(0, 0, -1), ang_rate=(0, 0, 0),
                           mag=(nan, nan, nan), timer=1000))
    path = tmp_path / "written.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        writer.serial(b"\x00\x01", 1.7e9, 10.0)
        for node in (76, 77):
            writer.message(f"gx2/{node}/accel_angrate_mag", strict({
                **record.as_dict(), "node": node, "record": record.name,
                "command": record.command, "seq": 1, "host_time": 1.7e9, "lqi": 255,
                "rssi": -40, "device_time": 0.1, "time": 1.7e9}))
        writer.message(STATUS, {"gateway": {"time": 1.7e9, "version": "0"}, "link": {},
                                "nodes": [], "recording": None, "replay": None})
        writer.message(MARK, {"text": "start", "time": 1.7e9, "host_time": 1.7e9,
                              "nodes": []})
        writer.finish()
    assert checked(path) == {"serial": 1, "gx2/76/accel_angrate_mag": 1,
                             "gx2/77/accel_angrate_mag": 1, STATUS: 1, MARK: 1}
    with path.open("rb") as stream:
        schemas = make_reader(stream).get_summary().schemas
    assert sorted(s.name for s in schemas.values()) == [
        "gx2.accel_angrate_mag", "gx2.gateway.mark", "gx2.gateway.status"]


def test_the_gateways_recording_and_gx2ctl_records_carry_schemas_every_message_meets(
        simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory)})
    gw.wait_streaming(76, 77)
    capture = tmp_path / "capture.mcap"
    record = Running("gx2ctl", "--control", gw.control_endpoint, "record", str(capture))
    wait_for(capture.exists, 10, "gx2ctl record to hear the gateway")
    for name in POLLED:
        assert gw.control.result("poll", node=76, record=name)["record"] == name
    marked = gx2ctl("--control", gw.control_endpoint, "mark", "76", "tapped")
    assert marked.status == 0, marked
    # a heartbeat after gx2ctl record heard the gateway (it made its file then)
    heard = gw.subscribe(STATUS, "gx2/77/")
    heard.until(lambda got: any(t == STATUS for t, _ in got) and len(got) >= 20, 10,
                "a status and records after the mark")
    record.proc.send_signal(signal.SIGINT)
    assert record.finish(10) == 0, record.stderr
    assert gw.terminate()[0] == 0, gw.log()

    expected = {STATUS, MARK, "gx2/76/accel_angrate", "gx2/77/accel_angrate_mag",
                *(f"gx2/76/{name}" for name in POLLED)}
    [recording] = directory.glob("*.mcap")
    for path in (recording, capture):
        counts = checked(path)
        assert expected <= set(counts), (path.name, counts)
    assert "serial" in checked(recording)
