"""The catalogue and windows on what the gateway recorded from gx2-sim: files rotated
by size, two trials marked with gx2ctl mark; ``gx2ctl recordings`` against the mcap
package's reading of the files, and each trial's export exactly the records logged
between its marks; and the same after retention deleted the first files, each trial
exported to CSV, Parquet and .mat. (A middle file deleted by hand:
tests/recording/test_windows.py.)"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

from mcap.reader import make_reader

from gateway.common.topics import parse
from gateway.recording.columns import nanoseconds
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
            if (where := parse(topic)) is not None:  # a record (a frame is none)
                node, record = str(where[0]), where[1]
                counts.setdefault(node, {}).setdefault(record, 0)
                counts[node][record] += 1
        assert described["nodes"] == counts
        assert described["stations"] == ["station1"]
        assert described["marks"] == [{"time": p["time"], "text": p["text"],
                                       "fields": p["fields"]}
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


DELETED = re.compile(r"recording: deleted (\S+) ")
ROTATE_BYTES = 20_000
KEEP_BYTES = 300_000
"""About twenty seconds of the two nodes: the trials, marked after a first deletion, are
well inside what is kept when the gateway stops (ten seconds were not, once: the four
gx2ctl marks took longer beside the suite's other processes, and the first was deleted)."""


def test_after_retention_deleted_the_first_files_windows_read_what_is_left(
        simulator, gateway, tmp_path: Path) -> None:
    """Retention (``record.keep_gb``) deletes the oldest files while the gateway
    records; the trials marked afterwards are exported, in every format, from exactly
    the messages of the files left, and the catalogue lists those files alone."""
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory),
                                          "rotate_mb": ROTATE_BYTES / 1e6,
                                          "keep_gb": KEEP_BYTES / 1e9})
    gw.wait_streaming(76, 77)
    wait_for(lambda: DELETED.search(gw.log()), 60, "retention deleting a file")
    samples = gw.subscribe("gx2/76/")
    control = ("--control", gw.control_endpoint)
    for text in ("start", "stop", "start", "stop", None):
        seen = len(samples.messages)
        samples.until(lambda m, seen=seen: len(m) >= seen + 30, 10, "records between marks")
        if text is not None:
            assert gx2ctl(*control, "mark", text).status == 0
    assert gw.terminate()[0] == 0, gw.log()
    deleted = {Path(name).name for name in DELETED.findall(gw.log())}
    files = sorted(directory.glob("*.mcap"))
    assert deleted and not deleted & {p.name for p in files}
    assert max(deleted) < files[0].name  # the oldest went first

    ran = gx2ctl("recordings", "--json", str(directory))
    assert ran.status == 0, ran.stderr
    assert [f["path"] for f in json.loads(ran.stdout)["files"]] == [str(p) for p in files]
    everything = [m for path in files for m in read_back(path)]

    # no window: every record left, none of the deleted files', nothing said missing
    out = tmp_path / "all"
    exported = gx2ctl("export", str(directory), "--out", str(out), "--node", "77")
    assert exported.status == 0 and exported.stderr == "", exported.stderr
    with (out / "77_euler.csv").open(newline="") as table:
        assert [float(row["host_time"]) for row in csv.DictReader(table)] == [
            p["host_time"] for topic, _, p in everything if topic == "gx2/77/euler"]

    marks = sorted(t for topic, t, _ in everything if topic == "gx2/gateway/mark")
    assert len(marks) == 4
    for form in ("csv", "parquet", "mat"):
        out = tmp_path / form
        exported = gx2ctl("export", str(directory), "--out", str(out), "--format", form,
                          "--between-marks", "start", "stop")
        assert exported.status == 0, exported.stderr
        folders = sorted(out.iterdir())
        assert len(folders) == 2
        for folder, (begin, end) in zip(folders, [marks[0:2], marks[2:4]], strict=True):
            inside = [p["host_time"] for topic, t, p in everything
                      if topic == "gx2/77/euler" and begin <= t <= end]
            assert len(inside) > 20
            assert sorted(p.name for p in folder.iterdir()) == [
                f"76_accel_angrate.{form}", f"77_euler.{form}", f"marks.{form}",
                "trial.json"]
            assert host_times_of(folder / f"77_euler.{form}", form) == (
                [nanoseconds(t) for t in inside] if form == "parquet" else inside)


def host_times_of(path: Path, form: str) -> list[float]:
    """The ``host_time`` column, read by each format's own reader: UNIX seconds (in
    Parquet a timestamp, given as its nanoseconds)."""
    if form == "csv":
        with path.open(newline="") as table:
            return [float(row["host_time"]) for row in csv.DictReader(table)]
    if form == "parquet":
        import pyarrow.parquet as pq
        column = pq.read_table(path).column("host_time")
        assert str(column.type) == "timestamp[ns, tz=UTC]"
        return column.cast("int64").to_pylist()
    from scipy.io import loadmat
    table = loadmat(path, simplify_cells=True)["n77_euler"]
    return [float(v) for v in table["host_time"]]


def test_two_stations_recorded_are_catalogued_by_station_and_a_trial_read_per_node(
        gateway, tmp_path: Path) -> None:
    """A gateway of two base stations (each its own serial channel in the files): the
    catalogue names both and each one's nodes; a trial of one node of the second
    station is exactly that node's records logged between the marks."""
    directory = tmp_path / "recordings"
    gw = gateway(None, [], base_stations=[
        {"name": "north", "port": "sim://", "nodes": [NODES[0]]},
        {"name": "south", "port": "sim://", "nodes": [NODES[1]]}],
        record={"directory": str(directory)})
    gw.wait_streaming(76, 77)
    samples = gw.subscribe("gx2/77/")
    control = ("--control", gw.control_endpoint)
    for text in ("start", "stop", None):
        seen = len(samples.messages)
        samples.until(lambda m, seen=seen: len(m) >= seen + 30, 10, "records between marks")
        if text is not None:
            assert gx2ctl(*control, "mark", text).status == 0
    assert gw.terminate()[0] == 0, gw.log()
    (path,) = sorted(directory.glob("*.mcap"))
    messages = read_back(path)

    ran = gx2ctl("recordings", "--json", str(directory))
    assert ran.status == 0, ran.stderr
    (described,) = json.loads(ran.stdout)["files"]
    assert sorted(described["stations"]) == ["north", "south"]
    assert set(described["nodes"]) == {"76", "77"}
    assert described["nodes"]["77"]["euler"] == sum(
        1 for topic, _, _ in messages if topic == "gx2/77/euler")

    out = tmp_path / "trial"
    exported = gx2ctl("export", str(path), "--out", str(out), "--between-marks", "start",
                      "stop", "--node", "77")
    assert exported.status == 0, exported.stderr
    begin, end = sorted(t for topic, t, _ in messages if topic == "gx2/gateway/mark")
    inside = [p["host_time"] for topic, t, p in messages
              if topic == "gx2/77/euler" and begin <= t <= end]
    (folder,) = out.iterdir()
    assert sorted(p.name for p in folder.iterdir()) == ["77_euler.csv", "marks.csv",
                                                        "trial.json"]
    assert host_times_of(folder / "77_euler.csv", "csv") == inside and len(inside) > 20
