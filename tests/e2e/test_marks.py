"""Marks (``gx2ctl mark``) through the real gateway on the simulator: published on
gx2/gateway/mark, kept by the gateway's own recording and by ``gx2ctl record`` (whatever
nodes it records), exported to marks.csv and drawn on a node's plot."""

from __future__ import annotations

import csv
import json
import random
import re
import signal
import time
from pathlib import Path

from mcap.opcode import Opcode
from mcap.reader import make_reader

from gateway.client import Recording
from gateway.recording.files import MAGIC, RECORD_HEAD
from gateway.recording.plot import picture, records_of
from gateway.recording.reader import read
from gateway.recording.reports import Reading
from gateway.sim.node import NodeSettings
from tests.helpers.processes import Running, gx2ctl
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}, {"address": 77, "stream": "euler"}]
MARK = "gx2/gateway/mark"


def marks_in(path: Path) -> list[dict]:
    """The marks of a file, read by the ``mcap`` package (never our reader)."""
    with path.open("rb") as stream:
        return [json.loads(message.data) for _, channel, message
                in make_reader(stream).iter_messages(log_time_order=False)
                if channel.topic == MARK]


def records_in(data: bytes) -> list[tuple[int, int, int]]:
    """The top-level records of an MCAP file's data: (offset, opcode, end)."""
    found, at = [], len(MAGIC)
    while at + RECORD_HEAD.size <= len(data):
        opcode, length = RECORD_HEAD.unpack_from(data, at)
        found.append((at, opcode, at + RECORD_HEAD.size + length))
        at = found[-1][2]
    return found


def test_marks_are_published_recorded_exported_and_drawn(simulator, gateway, tmp_path):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory)})
    gw.wait_streaming(76, 77)
    published = gw.subscribe(MARK)
    samples = gw.subscribe("gx2/76/")
    capture = tmp_path / "capture.mcap"
    record = Running("gx2ctl", "--control", gw.control_endpoint, "record", str(capture), "76")
    wait_for(capture.exists, 10, "gx2ctl record to hear the gateway")
    control = ("--control", gw.control_endpoint)

    tapped = gx2ctl(*control, "mark", "76", "left wing tapped")
    assert tapped.status == 0, tapped
    assert re.fullmatch(r"mark at \d\d:\d\d:\d\d\.\d{3} UTC: left wing tapped \(76\)\n",
                        tapped.stdout), tapped
    assert gx2ctl(*control, "mark", "77", "76", "77", "right wing tapped").status == 0
    started = gx2ctl(*control, "--json", "mark", "trial 1 start")
    assert started.status == 0, started
    # a node the gateway does not have is bad input (exit 2), and nothing is published
    unknown = gx2ctl(*control, "mark", "99", "nowhere")
    assert unknown.status == 2 and "node 99 is not configured" in unknown.stderr, unknown

    marks = [p for _, p in published.until(lambda m: len(m) >= 3, 10, "three marks")]
    assert [(m["text"], m["nodes"]) for m in marks] == [
        ("left wing tapped", [76]), ("right wing tapped", [77, 76]), ("trial 1 start", [])]
    assert marks[2] == json.loads(started.stdout)
    assert marks[0]["time"] < marks[1]["time"] < marks[2]["time"]
    assert all(m["host_time"] == m["time"] for m in marks)
    # records after the last mark, so that it lies within the plotted samples' time
    samples.until(lambda m: m and m[-1][1]["time"] > marks[2]["time"] + 0.1, 10,
                  "records after the marks")
    record.proc.send_signal(signal.SIGINT)
    assert record.finish(10) == 0, record.stderr
    assert gw.terminate()[0] == 0, gw.log()
    published.drain(0.1)
    assert len(published.messages) == 3

    [recording] = directory.glob("*.mcap")
    assert marks_in(recording) == marks
    assert marks_in(capture) == marks  # although it records node 76 alone

    out = tmp_path / "out"
    exported = gx2ctl("export", str(capture), "--out", str(out))
    assert exported.status == 0, exported
    with (out / "marks.csv").open() as table:
        rows = list(csv.DictReader(table))
    assert rows == [{"time": repr(m["time"]), "host_time": repr(m["host_time"]),
                     "nodes": " ".join(map(str, m["nodes"])), "text": m["text"]}
                    for m in marks]
    found = records_of([capture], 76, None, Reading())
    image = picture(76, found.record, found.payloads, found.name, found.marks)
    # node 76's marks and the experiment's, as labelled lines
    assert [text for _, text in image.marks] == [
        "left wing tapped", "right wing tapped", "trial 1 start"]


def test_a_mark_is_read_as_soon_as_mark_returns(simulator, gateway, tmp_path):
    """A mark is on the recording's disk when its answer comes: Recording, export and
    recordings read it at once, from the file still being written (issue 43: export
    said `no trial from a mark 'go' to a mark 'halt'` right after `mark halt`, and
    worked 1.5 s later; recordings listed no mark of the file being written, for up to
    the hour of rotate_minutes)."""
    sim = simulator(NodeSettings(76))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES[:1], record={"directory": str(directory),
                                              "rotate_minutes": 60})
    gw.wait_streaming(76)
    for trial in (1, 2, 3):  # (each at its own place in the recorder's second)
        for text in ("go", "halt"):
            made = gw.control.result("mark", text=text)
            seen = Recording(directory).marks()
            assert seen and (seen[-1].text, seen[-1].time) == (text, made["time"]), \
                (trial, text, seen)
        (last,) = Recording(directory, between_marks=("go", "halt"), trial=trial).trials()
        assert last.windows[0].label.startswith(f"trial-{trial}_")
    exported = gx2ctl("export", str(directory), "--out", str(tmp_path / "out"),
                      "--between-marks", "go", "halt", "--trial", "3")
    assert exported.status == 0, exported
    [listed] = json.loads(gx2ctl("recordings", "--json", str(directory)).stdout)["files"]
    assert listed["writing"] is True, listed
    assert [m["text"] for m in listed["marks"]] == ["go", "halt"] * 3, listed
    table = gx2ctl("recordings", str(directory)).stdout
    assert table.count("  go\n") == 3 and table.count("  halt\n") == 3, table
    assert gw.terminate()[0] == 0, gw.log()


def test_a_topic_read_of_a_recording_cut_anywhere_is_the_full_read_filtered(
        simulator, gateway, tmp_path):
    """A file without summary read for some topics (its marks) passes over a chunk whose
    message indexes name only other channels; a writer killed while it flushed them cut
    that list short, and the last mark (its index never written) was passed over:
    ``Recording.marks()`` missed a killed gateway's last mark. Cut at many places, the
    topic read of a real recording is its full read filtered."""
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory)})
    gw.wait_streaming(76, 77)
    texts = ["one", "two", "three", "four"]
    for text in texts:
        time.sleep(0.3)  # (records between the marks: each mark's chunk holds them too)
        gw.control.result("mark", text=text)
    assert gw.terminate()[0] == 0, gw.log()
    [recording] = directory.glob("*.mcap")
    with recording.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    mark = next(c.id for c in summary.channels.values() if c.topic == MARK)
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"

    def topics_read(*topics: str) -> tuple[list, list]:
        only = [(e.topic, e.log_time) for e in read(cut, Reading(), topics)]
        full = [(e.topic, e.log_time) for e in read(cut, Reading()) if e.topic in topics]
        return only, full

    # killed after writing some of a mark's chunk's message indexes, not the mark's
    records = records_in(data)
    killed = []
    for n, (_, opcode, _) in enumerate(records):
        indexes = []
        for at_index, index_opcode, index_end in records[n + 1:]:
            if index_opcode != Opcode.MESSAGE_INDEX:
                break
            indexes.append((at_index, index_end, int.from_bytes(
                data[at_index + RECORD_HEAD.size:at_index + RECORD_HEAD.size + 2],
                "little")))
        channels = [channel for _, _, channel in indexes]
        if opcode == Opcode.CHUNK and mark in channels[1:]:
            before = indexes[channels.index(mark) - 1]
            killed += [before[1], before[1] + 5, before[0] + 5]  # (after, in, in the one before)
    assert killed, "no mark's chunk with another channel's index before the mark's"
    for end in killed:
        cut.write_bytes(data[:end])
        only, full = topics_read(MARK)
        assert only == full and full, end
        seen = [m.text for m in Recording(cut).marks()]
        assert seen == texts[:len(seen)] and seen, (end, seen)
    assert seen == texts  # (the last mark's chunk: its marks include the last one)
    # cut anywhere
    chosen = random.Random(43)
    for end in sorted(chosen.sample(range(len(MAGIC) + 1, len(data)), 40)):
        cut.write_bytes(data[:end])
        for topics in ([MARK], ["gx2/77/euler"], [MARK, "gx2/76/accel_angrate"]):
            only, full = topics_read(*topics)
            assert only == full, (end, topics, len(only), len(full))
