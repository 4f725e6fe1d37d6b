"""What ``--time refined`` reads of a recording (gateway.recording.sightings) and what it
refuses: on a recording written here, read by read, whose every packet's arrival and
wait is known, and on a file of gx2ctl record's, which holds no serial reads."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from aspp.records import encode
from aspp.timing import TICKS_PER_SECOND
from gateway.client import Recording, RecordingError, Unrefinable
from gateway.recording.columns import nanoseconds
from gateway.recording.files import RecordingError as FilesRecordingError
from gateway.recording.refined import line_settings
from gateway.recording.sightings import LineSettings, Sightings
from gateway.recording.writer import RecordingWriter
from tests.helpers.packets import pkt
from tests.helpers.processes import gx2ctl, gx2ctl_here
from tests.helpers.recorded import T0, make_file

BYTE = 10 / 115200
SHIFT = T0 - 1000.0
"""UNIX less monotonic, at every read here."""
LATENCY = 0.003


def packet(node: int, timer: int) -> bytes:
    return pkt(encode("accel_angrate", accel=(0.0, 0.0, -1.0), ang_rate=(0.0, 0.0, 0.0),
                      timer=timer), node=node)


def record(node: int, seq: int, timer: int, device: float, read: float) -> dict:
    return {"node": node, "record": "accel_angrate", "command": 0xC2, "seq": seq,
            "host_time": read + SHIFT, "time": read + SHIFT - 0.005,
            "device_time": device, "timer": timer, "lqi": 100, "rssi": -44,
            "accel": [0.0, 0.0, -1.0], "ang_rate": [0.0, 0.0, 0.0]}


READS = [
    # (monotonic read, [(node, seq, timer, device)]): the first packet read after the port
    # opened (waited: what came before it is unknown); one 20 ms later (free); one that
    # began as the one before it ended (waited); two in one read, the second waited
    # behind the first; node 11's timer restarted (a reboot: a new power-up, its device
    # time going on)
    (1000.000, [(11, 1, 19_660_800, 1.0)]),
    (1000.020, [(11, 2, 19_660_800 + 196_608, 1.01)]),
    (1000.020 + 40 * BYTE + 0.0001, [(12, 1, 500, 0.0000254)]),
    (1000.060, [(11, 3, 19_660_800 + 2 * 196_608, 1.02), (12, 2, 500 + 196_608, 0.0100254)]),
    (1000.100, [(11, 4, 1000, 1.03)]),
]


def written(path: Path, metadata: dict[str, str] | None = None) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output, metadata or {"baudrate": "115200",
                                                      "latency_ms": "3"})
        for read, packets in READS:
            data = b"".join(packet(node, timer) for node, _, timer, _ in packets)
            writer.serial(data, read + SHIFT, read)
            for node, seq, timer, device in packets:
                writer.message(f"gx2/{node}/accel_angrate",
                               record(node, seq, timer, device, read))
        # a record whose packet no read holds: kept as recorded
        writer.message("gx2/12/accel_angrate", record(12, 3, 500 + 2 * 196_608, 0.0200254,
                                                      1000.120))
        writer.message("gx2/11/euler", {"node": 11, "record": "euler", "command": 0xCE,
                                        "seq": 5, "host_time": 1000.13 + SHIFT,
                                        "roll": 0.1, "pitch": 0.2, "yaw": 0.3})
        writer.finish()
    return path


def test_each_record_is_matched_to_its_packet_and_its_wait_judged_as_live(
        tmp_path: Path) -> None:
    from gateway.recording.reader import read
    from gateway.recording.reports import Reading
    path = written(tmp_path / "line.mcap")
    assert line_settings([path]) == {"serial": LineSettings(BYTE, LATENCY)}
    sightings = Sightings(line_settings([path]), LineSettings(BYTE, 0.0))
    for entry in read(path, Reading()):
        payload = None if entry.topic == "serial" else json.loads(entry.data)
        sightings.feed(entry.topic, entry.log_time, entry.publish_time, entry.data,
                       payload, True)
    assert sightings.reads == len(READS)
    by_node = {}
    for power_up in sightings.power_ups:
        by_node.setdefault(power_up.node, []).append(power_up)
    (first, rebooted), (other,) = by_node[11], by_node[12]
    assert first.device == [1.0, 1.01, 1.02] and rebooted.device == [1.03]
    assert first.waited == [True, False, False] and other.waited == [True, True]
    assert first.arrival[1] == pytest.approx(1000.020 - 40 * BYTE)
    assert other.arrival[1] == pytest.approx(1000.060 - 40 * BYTE)  # (its read's, its bytes)
    # line + shift = time: the live line is each time with its read's conversion undone
    assert first.shift[0] == pytest.approx(SHIFT - LATENCY)
    assert first.live[0] == pytest.approx(1000.0 - 0.005 + LATENCY)
    rows = sightings.rows
    assert [row[1] is None for row in rows["gx2/12/accel_angrate"]] == [False, False, True]
    assert [row[1] is None for row in rows["gx2/11/euler"]] == [True]


def test_a_refined_export_says_how_each_row_was_placed(tmp_path: Path) -> None:
    path = written(tmp_path / "line.mcap")
    ran = gx2ctl("export", str(path), "--out", str(tmp_path / "out"), "--time", "refined")
    assert ran.status == 0, ran.stderr
    with (tmp_path / "out" / "12_accel_angrate.csv").open() as table:
        rows = list(csv.DictReader(table))
    assert list(rows[0])[:4] == ["time", "time_placed", "time_bound_ms", "host_time"]
    # node 12's packets all waited: unplaceable; the one no read holds, as recorded
    assert [r["time_placed"] for r in rows] == ["unplaceable", "unplaceable", "live"]
    assert rows[2]["time"] == repr(1000.120 + SHIFT - 0.005)
    assert [r["time_bound_ms"] for r in rows] == ["", "", ""]
    with (tmp_path / "out" / "11_euler.csv").open() as table:
        (euler,) = csv.DictReader(table)
    assert euler["time"] == euler["time_placed"] == euler["time_bound_ms"] == ""
    # live: the columns as they always were
    ran = gx2ctl("export", str(path), "--out", str(tmp_path / "live"))
    assert ran.status == 0, ran.stderr
    with (tmp_path / "live" / "12_accel_angrate.csv").open() as table:
        assert "time_placed" not in next(csv.DictReader(table))


def test_parquet_and_mat_hold_the_refined_times_csv_holds(tmp_path: Path) -> None:
    """Parquet is written a batch at a time from the messages' own JSON, which holds
    the recorded time: a refined export goes row by row, as CSV and .mat do, with the
    same rows and the two columns typed."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from scipy.io import loadmat
    path = written(tmp_path / "line.mcap")
    for form in ("csv", "parquet", "mat"):
        ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / form), "--time", "refined",
                          "--format", form)
        assert ran.status == 0, ran.stderr
    with (tmp_path / "csv" / "12_accel_angrate.csv").open() as table:
        rows = list(csv.DictReader(table))
    parquet = pq.read_table(tmp_path / "parquet" / "12_accel_angrate.parquet")
    assert parquet.column_names[:4] == ["time", "time_placed", "time_bound_ms", "host_time"]
    assert parquet.schema.field("time_placed").type == pa.string()
    assert parquet.schema.field("time_bound_ms").type == pa.float64()
    assert parquet.column("time_placed").to_pylist() == [r["time_placed"] for r in rows]
    assert parquet.column("time_bound_ms").to_pylist() == [None] * len(rows)
    assert [t.value for t in parquet.column("time")] == [
        nanoseconds(float(r["time"])) for r in rows]  # (the decimal written, exactly)
    assert parquet.column("lost_before").to_pylist() == [
        int(r["lost_before"]) if r["lost_before"] else None for r in rows]
    mat = loadmat(tmp_path / "mat" / "12_accel_angrate.mat", simplify_cells=True)
    table = mat["n12_accel_angrate"]
    assert list(table)[:3] == ["time", "time_placed", "time_bound_ms"]
    assert list(table["time"]) == [float(r["time"]) for r in rows]


def test_gx2ctls_choices_of_time_are_the_librarys() -> None:
    """gx2ctl's parser names them without importing the refinement (its start stays
    light): the same as the library's."""
    from gateway.ctl import offline
    from gateway.recording import refined

    assert offline.TIMES == refined.TIMES


def test_bad_times_and_recordings_that_cannot_be_refined_are_one_line(tmp_path: Path) -> None:
    published = make_file(tmp_path / "published.mcap", 0, 3)  # (gx2ctl record's: no bytes)
    cases = {
        ("--time", "bogus"): "gx2ctl export: argument --time: invalid choice: 'bogus'",
        ("--time", "refined"): f"gx2ctl: {published}: no serial reads, and the refined "
                               "time needs them",
        ("--time", "refined", "--format", "ros2"): "gx2ctl: --time refined is for the "
                                                   "tables",
    }
    for args, start in cases.items():
        ran = gx2ctl_here("export", str(published), "--out", str(tmp_path / "out"), *args)
        assert ran.status == 2, (args, ran)
        assert ran.stderr.startswith(start) and ran.stderr.count("\n") == 1, ran.stderr
        assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    # refused before --force removes an earlier export's tables
    earlier = gx2ctl_here("export", str(published), "--out", str(tmp_path / "earlier"))
    assert earlier.status == 0, earlier.stderr
    before = sorted((tmp_path / "earlier").iterdir())
    ran = gx2ctl_here("export", str(published), "--out", str(tmp_path / "earlier"), "--time",
                      "refined", "--force")
    assert ran.status == 2 and "no serial reads" in ran.stderr, ran
    assert sorted((tmp_path / "earlier").iterdir()) == before
    # the client says the same, as exceptions
    with pytest.raises(ValueError, match="time must be one of 'live', 'refined'"):
        Recording(published, time="bogus")
    with pytest.raises(Unrefinable, match="no serial reads"):
        Recording(published, time="refined")
    assert issubclass(Unrefinable, RecordingError) and RecordingError is FilesRecordingError


def test_the_client_gives_the_refined_times_export_writes(tmp_path: Path) -> None:
    path = written(tmp_path / "line.mcap")
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"), "--time", "refined")
    assert ran.status == 0, ran.stderr
    with (tmp_path / "out" / "12_accel_angrate.csv").open() as table:
        exported = [(float(r["time"]), r["time_placed"]) for r in csv.DictReader(table)]
    messages = [m for m in Recording(path, nodes=[12], time="refined")]
    assert [(m.time, m["time_placed"]) for m in messages] == exported
    assert "time_placed" not in messages[0].fields
    frame = Recording(path, nodes=[12], time="refined").to_pandas()
    assert list(frame.columns[6:9]) == ["time", "time_placed", "time_bound_ms"]


def test_several_stations_each_read_at_its_own_line(tmp_path: Path) -> None:
    # two base stations' reads on their own channels, at their own baud rates and
    # latencies (the head's stations): a packet's arrival is its read's less its bytes
    # at its own line's rate, and its wait is judged against its own line only
    stations = [{"name": "left", "port": "/dev/a", "baudrate": 115200, "latency_ms": 3,
                 "nodes": [11]},
                {"name": "right", "port": "/dev/b", "baudrate": 57600, "latency_ms": 5,
                 "nodes": [12]}]
    path = tmp_path / "two.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output, {"stations": json.dumps(stations)})
        reads = [1000.0, 1000.010, 1000.0105, 1000.021]
        for at, (node, topic) in enumerate([(11, "serial/left"), (12, "serial/right")] * 2):
            read = reads[at]
            timer = 196_608 * (1 + at)  # (10 ms steps; device time is the timer's)
            writer.serial(packet(node, timer), read + SHIFT, read, topic)
            writer.message(f"gx2/{node}/accel_angrate",
                           record(node, 1 + at, timer, timer / TICKS_PER_SECOND, read))
        writer.finish()
    settings = line_settings([path])
    assert settings == {"serial/left": LineSettings(BYTE, 0.003),
                        "serial/right": LineSettings(2 * BYTE, 0.005)}
    from gateway.recording.reader import read
    from gateway.recording.reports import Reading
    sightings = Sightings(settings, LineSettings(BYTE, 0.0))
    for entry in read(path, Reading()):
        payload = None if entry.topic.startswith("serial") else json.loads(entry.data)
        sightings.feed(entry.topic, entry.log_time, entry.publish_time, entry.data,
                       payload, True)
    left, right = sightings.power_ups
    assert (left.node, right.node) == (11, 12)
    assert right.arrival[0] == pytest.approx(1000.010 - 40 * 2 * BYTE)
    assert right.shift[0] == pytest.approx(SHIFT - 0.005)
    # the first packet of each, after nothing read on its line: waited (unknown); the
    # second of the left began 7 ms after its own line's last packet, whatever the
    # right line read just before it: free
    assert left.waited == right.waited == [True, False]


def test_plot_draws_the_refined_times_export_writes(tmp_path: Path) -> None:
    """``gx2ctl plot --time refined``: the time axis is the refined time, the same as
    export gives (the library's records_of, which plot draws), and a recording that
    cannot be refined is one line, exit 2, no picture."""
    from gateway.recording.catalogue import catalogue
    from gateway.recording.plot import records_of
    from gateway.recording.refined import for_window
    from gateway.recording.reports import Reading
    from gateway.recording.window import Reader, Window

    path = written(tmp_path / "line.mcap")
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"), "--time", "refined")
    assert ran.status == 0, ran.stderr
    with (tmp_path / "out" / "11_accel_angrate.csv").open() as table:
        exported = [(float(r["time"]), r["time_placed"]) for r in csv.DictReader(table)]
    files, whole, reading = catalogue([path]), Window(None), Reading()
    found = records_of([path], 11, "accel_angrate", reading,
                       Reader(files, reading).entries(whole), for_window(files, whole))
    assert [(p["time"], p["time_placed"]) for p in found.payloads] == exported

    ran = gx2ctl_here("plot", str(path), "11", "--time", "refined",
                      "--out", str(tmp_path / "refined.png"))
    assert ran.status == 0, ran.stderr
    assert (tmp_path / "refined.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    published = make_file(tmp_path / "published.mcap", 0, 3)  # (no serial reads)
    ran = gx2ctl_here("plot", str(published), "76", "--time", "refined",
                      "--out", str(tmp_path / "no.png"))
    assert ran.status == 2 and ran.stderr.count("\n") == 1, ran
    assert "no serial reads" in ran.stderr and not (tmp_path / "no.png").exists()


def test_a_dataset_of_refined_times_holds_what_export_refines(tmp_path: Path) -> None:
    """``gx2ctl dataset --time refined``: each part's rows with the times export --time
    refined gives them and the two columns; the dataset keeps to one kind of time (a
    run asking the other is one line, exit 2, nothing changed), and a recording that
    cannot be refined is said and left, the run partial (exit 1)."""
    import pyarrow.parquet as pq

    recordings = tmp_path / "recordings"
    recordings.mkdir()
    path = written(recordings / "line.mcap")
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "tables"), "--time", "refined")
    assert ran.status == 0, ran.stderr
    with (tmp_path / "tables" / "11_accel_angrate.csv").open() as table:
        exported = [(float(r["time"]), r["time_placed"]) for r in csv.DictReader(table)]
    out = tmp_path / "dataset"
    ran = gx2ctl_here("dataset", str(recordings), str(out), "--time", "refined")
    assert ran.status == 0, ran.stderr
    (part,) = out.glob("record=accel_angrate/node=11/date=*/part-line.parquet")
    rows = pq.read_table(part).to_pylist()
    assert [r["time_placed"] for r in rows] == [placed for _, placed in exported]
    assert [r["time"].timestamp() for r in rows] == pytest.approx([t for t, _ in exported],
                                                                  abs=1e-6)
    assert list(rows[0])[:3] == ["time", "time_placed", "time_bound_ms"]

    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    ran = gx2ctl_here("dataset", str(recordings), str(out))  # (live: the default)
    assert ran.status == 2 and ran.stderr.count("\n") == 1, ran
    assert "is a dataset of refined times" in ran.stderr
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before

    make_file(recordings / "published.mcap", 0, 3)  # (gx2ctl record's: no serial reads)
    ran = gx2ctl_here("dataset", str(recordings), str(out), "--time", "refined")
    assert ran.status == 1, ran
    assert "published.mcap: no serial reads" in ran.stderr
    assert "1 not converted (each said why" in ran.stdout and "unreadable" not in ran.stdout


def test_a_row_the_first_pass_read_among_other_recordings_rows_is_found_by_its_time() -> None:
    """A dataset's recording is refined from the recordings around it: where one of
    them overlaps it, the first pass's rows of a topic begin with that one's, more than
    the lookahead, and the second pass reads this recording's alone. Each row is found
    by its log_time (before: every row kept live, silently; an outside review's
    reproduction, 259 rows placed between by export, none by the dataset)."""
    from gateway.recording.reader import Entry
    from gateway.recording.refined import LOOKAHEAD, Refinement

    topic = "gx2/12/accel_angrate"
    other = [(stamp, (float(stamp), "live", None)) for stamp in range(2 * LOOKAHEAD)]
    mine = [(1000 + stamp, (5.0 + stamp, "between", 0.1)) for stamp in range(5)]
    refinement = Refinement({topic: other + mine})
    placed = [refinement.apply(Entry(topic, stamp, stamp, b""), {"time": 1.0})
              for stamp, _ in mine]
    assert [(p["time"], p["time_placed"]) for p in placed] == \
        [(time, how) for _, (time, how, _) in mine]


def test_a_quiet_recording_is_converted_with_no_rows_into_a_refined_dataset(
        tmp_path: Path) -> None:
    """A gateway's recording that holds no record (started and stopped, or its nodes
    off for a whole file) has nothing to refine: 0 rows, as a live dataset converts it
    (before: "no serial reads", never converted, every run exit 1)."""
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    written(recordings / "line.mcap")
    with (recordings / "quiet.mcap").open("wb") as output:
        writer = RecordingWriter(output, {"baudrate": "115200", "latency_ms": "3"})
        for second in range(3):
            writer.message("gx2/gateway/status", {"gateway": {"time": T0 + 10 + second},
                                                  "nodes": []})
        writer.finish()
    ran = gx2ctl_here("dataset", str(recordings), str(tmp_path / "out"), "--time", "refined")
    assert ran.status == 0, ran
    assert "quiet.mcap  0 rows" in ran.stdout and "2 converted" in ran.stdout
