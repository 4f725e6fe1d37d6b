"""The catalogue and windows on what the gateway recorded from gx2-sim: files rotated
by size, two trials marked with gx2ctl mark; ``gx2ctl recordings`` against the mcap
package's reading of the files, and each trial's export exactly the records logged
between its marks."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from mcap.reader import make_reader

from gateway.sim.node import NodeSettings
from tests.helpers.processes import gx2ctl
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate"}, {"address": 77, "stream": "euler"}]


def read_back(path: Path) -> list[tuple[str, int, dict | None]]:
    with path.open("rb") as stream:
        return [(channel.topic, message.log_time,
                 json.loads(message.data) if channel.message_encoding == "json" else None)
                for _, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False)]


def test_trials_marked_on_the_gateway_are_catalogued_and_exported(simulator, gateway,
                                                                   tmp_path: Path) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory), "rotate_mb": 0.05})
    gw.wait_streaming(76, 77)
    samples = gw.subscribe("gx2/76/")
    control = ("--control", gw.control_endpoint)
    for i, text in enumerate(("start", "stop", "start", "stop", None)):
        seen = len(samples.messages)
        samples.until(lambda m, seen=seen: len(m) >= seen + 30, 10, "records between marks")
        if text is not None:
            assert gx2ctl(*control, "mark", text).status == 0
        if i == 2:  # the second trial across files
            wait_for(lambda: len(list(directory.glob("*.mcap"))) >= 2, 20, "a rotation")
    assert gw.terminate()[0] == 0, gw.log()
    files = sorted(directory.glob("*.mcap"))
    assert len(files) >= 2  # rotated

    ran = gx2ctl("recordings", "--json", str(directory))
    assert ran.status == 0, ran.stderr
    listed = json.loads(ran.stdout)["files"]
    assert [f["path"] for f in listed] == [str(p) for p in files]
    everything = []
    for described, path in zip(listed, files, strict=True):
        messages = read_back(path)
        everything += messages
        assert described["start"] == min(t for _, t, _ in messages) / 1e9
        assert described["end"] == max(t for _, t, _ in messages) / 1e9
        counts: dict[str, dict[str, int]] = {}
        for topic, _, _ in messages:
            if topic.startswith("gx2/7"):
                _, node, record = topic.split("/")
                counts.setdefault(node, {}).setdefault(record, 0)
                counts[node][record] += 1
        assert described["nodes"] == counts
        assert described["stations"] == ["station1"]
        assert described["marks"] == [{"time": p["time"], "text": p["text"]}
                                      for t, _, p in messages if t == "gx2/gateway/mark"]
        assert described["damaged"] is False and described["indexed"] is True

    out = tmp_path / "trials"
    exported = gx2ctl("export", str(directory), "--out", str(out), "--between-marks",
                      "start", "stop")
    assert exported.status == 0, exported.stderr
    marks = sorted((t, p["text"]) for topic, t, p in everything
                   if topic == "gx2/gateway/mark")
    folders = sorted(out.iterdir())
    assert len(folders) == 2
    for folder, (begin, end) in zip(folders, [(marks[0][0], marks[1][0]),
                                              (marks[2][0], marks[3][0])], strict=True):
        inside = sorted(p["host_time"] for topic, t, p in everything
                        if topic == "gx2/77/euler" and begin <= t <= end)
        with (folder / "77_euler.csv").open(newline="") as table:
            assert [float(row["host_time"]) for row in csv.DictReader(table)] == inside
        assert len(inside) > 20
