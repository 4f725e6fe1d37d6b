"""gx2ctl export and plot, run as users run them, on recordings written through the
recording writer from payloads shaped as the gateway publishes them."""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from matplotlib import pyplot
from mcap.reader import make_reader
from mcap.writer import Writer
from scipy.io import loadmat

from aspp.orientation import matrix_from_euler
from aspp.records import BY_NAME, decode, encode
from gateway.recording.figure import figure_of
from gateway.recording.marks import Mark
from gateway.recording.plot import picture, records_of
from gateway.recording.reports import Reading
from gateway.recording.writer import RecordingWriter
from gateway.sim.node import GX2, NodeSettings, SimNode
from tests.helpers.processes import gx2ctl, gx2ctl_here

NAN = float("nan")
T0 = 1_795_000_000.0


def payload(node: int, record: str, seq: int, at: float, **fields: object) -> dict:
    """A published record: the decoded fields, plus what the gateway adds."""
    values = decode(encode(record, **fields)).as_dict()
    out = {**{k: list(v) if isinstance(v, tuple) else v for k, v in values.items()},
           "node": node, "record": record, "command": 0, "seq": seq,
           "host_time": at + 0.004, "lqi": 200, "rssi": -50}
    if "timer" in out:
        out["device_time"] = at - T0
        out["time"] = at
    return out


def write(path: Path, entries: list[tuple[str, dict]], cut: int = 0) -> Path:
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for topic, data in entries:
            writer.message(topic, data)
        writer.flush()
        if cut:
            output.flush()
            data = path.read_bytes()
            path.write_bytes(data[:len(data) - cut])
            return path
        writer.finish()
    return path


def nested(matrix: tuple) -> list:
    return [list(row) for row in matrix]


@pytest.fixture
def recording(tmp_path: Path) -> tuple[Path, list[dict]]:
    """Node 76 at 100 Hz with three samples lost over the radio (its timer skips them,
    seq does not) and two lost by the gateway (seq skips them too); node 77's
    orientation matrix; a magnetometer of NaN; an untimed record; the status naming
    node 76."""
    entries: list[tuple[str, dict]] = [("gx2/gateway/status", {
        "gateway": {"time": T0}, "nodes": [{"node": 76, "name": "left-wing"}]})]
    streamed = []
    seq = 0
    for i in range(200):
        if i in (50, 51, 52):
            continue  # lost over the radio: the timer skips them, seq does not
        seq += 2 if i == 122 else 1  # 120 and 121 lost by the gateway: seq skips too
        if i in (120, 121):
            continue
        p = payload(76, "accel_angrate_mag", seq, T0 + i / 100, timer=i * 196_608,
                    accel=(0.01 * i, 0.0, -1.0), ang_rate=(0.0, 0.5, 0.0), mag=(NAN,) * 3)
        streamed.append(p)
        entries.append(("gx2/76/accel_angrate_mag", p))
    matrix = ((1.0, 0.0, 0.0), (0.0, 0.5, -0.5), (0.0, 0.5, 0.5))
    entries.append(("gx2/77/orientation", payload(77, "orientation", 1, T0 + 1, timer=9,
                                                  orientation=matrix)))
    entries.append(("gx2/76/firmware_version", payload(76, "firmware_version", seq + 1,
                                                       T0 + 2, version=2104)))
    return write(tmp_path / "run.mcap", entries), streamed


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


def test_export_csv_columns_values_and_empty_cells(recording, tmp_path):
    path, streamed = recording
    ran = gx2ctl("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran.stderr
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == [
        "76_accel_angrate_mag.csv", "76_firmware_version.csv", "77_orientation.csv",
        "marks.csv"]  # (its header alone: the recording holds no mark)
    table = rows(out / "76_accel_angrate_mag.csv")
    with (out / "76_accel_angrate_mag.csv").open() as file:
        header = file.readline().strip().split(",")
    assert header == ["time", "host_time", "device_time", "seq", "lost_before", "lqi", "rssi",
                      "accel_x", "accel_y", "accel_z", "ang_rate_x", "ang_rate_y",
                      "ang_rate_z", "mag_x", "mag_y", "mag_z", "timer"]
    assert len(table) == len(streamed) == 195
    for row, sent in zip(table, streamed, strict=True):
        assert float(row["time"]) == sent["time"]
        assert float(row["host_time"]) == sent["host_time"]
        assert int(row["seq"]) == sent["seq"] and int(row["timer"]) == sent["timer"]
        assert [float(row[f"accel_{a}"]) for a in "xyz"] == sent["accel"]
        assert row["mag_x"] == row["mag_y"] == row["mag_z"] == ""  # NaN
    # the first row: what came before it is not known; after it, the samples its timer
    # skipped, whoever lost them (row 50 is i = 53, row 117 is i = 122), and none else
    lost = [row["lost_before"] for row in table]
    assert lost[0] == "" and lost[50] == "3" and lost[117] == "2"
    assert set(lost[1:50] + lost[51:117] + lost[118:]) == {"0"}
    [matrix] = rows(out / "77_orientation.csv")
    assert [float(matrix[f"orientation_{r}{c}"]) for r in (1, 2, 3) for c in (1, 2, 3)] == [
        1.0, 0.0, 0.0, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5]
    [untimed] = rows(out / "76_firmware_version.csv")
    assert untimed["time"] == untimed["device_time"] == "" and untimed["version"] == "2104"
    assert untimed["lost_before"] == ""  # no timer: nothing to count by
    assert "195 rows" in ran.stdout


def seconds_text(ns: int) -> str:
    """Nanoseconds written as the shortest decimal of seconds, as a message's JSON
    writes a float of seconds."""
    whole, fraction = divmod(ns, 1_000_000_000)
    return f"{whole}.{fraction:09d}".rstrip("0").rstrip(".") if fraction else f"{whole}.0"


def test_export_parquet_types_units_and_values(recording, tmp_path):
    path, streamed = recording
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path), "--format", "parquet")
    assert ran.status == 0, ran.stderr
    table = pq.read_table(tmp_path / "76_accel_angrate_mag.parquet")
    schema = table.schema
    assert schema.names[:8] == ["time", "host_time", "device_time", "seq", "lost_before",
                                "lqi", "rssi", "accel_x"]
    assert schema.field("time").type == pa.timestamp("ns", tz="UTC")
    assert schema.field("host_time").type == pa.timestamp("ns", tz="UTC")
    assert schema.field("device_time").type == pa.duration("ns")
    assert [schema.field(n).type for n in ("seq", "lqi", "rssi", "timer", "accel_x")] == [
        pa.int64(), pa.uint8(), pa.int8(), pa.uint32(), pa.float64()]
    # units and meanings from the record table, through the recordings' JSON Schemas
    notes = {n: schema.field(n).metadata for n in ("accel_x", "ang_rate_z", "time", "rssi",
                                                   "timer", "lost_before")}
    assert [notes[n][b"unit"] for n in notes] == [b"g", b"rad/s", b"s", b"dBm", b"ticks",
                                                  b"samples"]
    assert b"UNIX time when the sample was taken" in notes["time"][b"description"]
    values = {n: table.column(n).cast(pa.int64()).to_pylist()
              for n in ("time", "host_time", "device_time")}
    # every time is the decimal its message held, to the nanosecond (round(t * 1e9)
    # is off by up to 128 ns for most of them)
    assert [seconds_text(t) for t in values["host_time"]] == [
        repr(p["host_time"]) for p in streamed]
    assert [seconds_text(t) for t in values["time"]] == [repr(p["time"]) for p in streamed]
    assert [round(d / 1e9, 6) for d in values["device_time"]] == [
        round(p["device_time"], 6) for p in streamed]
    rows = table.select(["seq", "lost_before", "accel_x", "mag_z"]).to_pydict()
    assert rows["lost_before"] == [None, *[0] * 49, 3, *[0] * 66, 2, *[0] * 77]
    assert rows["seq"] == [p["seq"] for p in streamed]
    assert rows["accel_x"] == [p["accel"][0] for p in streamed]
    assert rows["mag_z"] == [None] * len(streamed)
    untimed = pq.read_table(tmp_path / "76_firmware_version.parquet").to_pydict()
    assert untimed["time"] == untimed["device_time"] == [None]
    assert untimed["version"] == [2104]


def test_export_parquet_host_time_is_the_recordings_log_time(recording, tmp_path):
    """To within the 256 ns the recorder's own rounding of host_time allows."""
    path, _ = recording
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path), "--format", "parquet")
    assert ran.status == 0, ran.stderr
    host = pq.read_table(tmp_path / "76_accel_angrate_mag.parquet").column(
        "host_time").cast(pa.int64()).to_pylist()
    with path.open("rb") as file:
        logged = [message.log_time for _, channel, message in
                  make_reader(file).iter_messages(topics=["gx2/76/accel_angrate_mag"])]
    assert len(host) == len(logged) and all(
        abs(h - t) <= 256 for h, t in zip(host, logged, strict=True))


def test_export_marks_parquet_and_mat(tmp_path):
    mark = {"text": "start", "time": T0 + 0.5, "host_time": T0 + 0.5, "nodes": [76, 77]}
    path = write(tmp_path / "marks.mcap", [("gx2/gateway/mark", mark), (
        "gx2/76/euler", payload(76, "euler", 1, T0, timer=1, roll=0.1, pitch=0.2,
                                yaw=0.3))])
    for form in ("parquet", "mat"):
        ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / form), "--format", form)
        assert ran.status == 0, ran.stderr
        assert f"marks.{form}  1 marks" in ran.stdout
    marks = pq.read_table(tmp_path / "parquet" / "marks.parquet")
    assert marks.schema.field("time").type == pa.timestamp("ns", tz="UTC")
    assert marks.schema.field("time").metadata[b"unit"] == b"s"
    assert marks.to_pydict()["nodes"] == ["76 77"]
    assert marks.column("time").cast(pa.int64()).to_pylist() == [1_795_000_000_500_000_000]
    loaded = loadmat(tmp_path / "mat" / "marks.mat", simplify_cells=True)["marks"]
    assert loaded["time"] == T0 + 0.5 and loaded["text"] == "start"
    assert loaded["nodes"] == "76 77" and loaded["units"]["time"] == "s"


def test_export_mat_holds_a_struct_a_table_with_units(recording, tmp_path):
    path, streamed = recording
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path), "--format", "mat")
    assert ran.status == 0, ran.stderr
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".mat") == [
        "76_accel_angrate_mag.mat", "76_firmware_version.mat", "77_orientation.mat",
        "marks.mat"]
    assert f"76_accel_angrate_mag.mat  {len(streamed)} rows" in ran.stdout
    content = loadmat(tmp_path / "76_accel_angrate_mag.mat")
    assert [k for k in content if not k.startswith("__")] == ["n76_accel_angrate_mag"]
    struct = content["n76_accel_angrate_mag"][0, 0]
    assert struct["time"].shape == (len(streamed), 1)  # column vectors of doubles
    assert struct["time"].dtype.name == "float64"
    assert struct["time"][:, 0].tolist() == [p["time"] for p in streamed]
    assert struct["seq"][:, 0].tolist() == [p["seq"] for p in streamed]
    assert struct["accel_x"][:, 0].tolist() == [p["accel"][0] for p in streamed]
    assert all(math.isnan(v) for v in struct["mag_z"][:, 0])  # NaN stays NaN
    lost = struct["lost_before"][:, 0].tolist()
    assert math.isnan(lost[0]) and lost[50] == 3 and lost[117] == 2
    units = struct["units"][0, 0]
    assert units["accel_x"][0] == "g" and units["ang_rate_y"][0] == "rad/s"
    assert units["time"][0] == "s" and units["timer"][0] == "ticks"
    assert "UNIX time" in struct["descriptions"][0, 0]["time"][0]
    untimed = loadmat(tmp_path / "76_firmware_version.mat", simplify_cells=True)
    assert math.isnan(untimed["n76_firmware_version"]["time"])
    assert untimed["n76_firmware_version"]["version"] == 2104
    matrix = loadmat(tmp_path / "77_orientation.mat", simplify_cells=True)["n77_orientation"]
    assert [matrix[f"orientation_{r}{c}"] for r in (1, 2, 3) for c in (1, 2, 3)] == [
        1.0, 0.0, 0.0, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5]


def test_a_file_cut_short_and_several_files_export_in_order(tmp_path):
    first = [payload(76, "euler", i + 1, T0 + i / 100, timer=i, roll=0.1, pitch=0.2,
                     yaw=0.3) for i in range(300)]
    second = [payload(76, "euler", i + 301, T0 + 3 + i / 100, timer=300 + i, roll=0.1,
                      pitch=0.2, yaw=0.3) for i in range(100)]
    directory = tmp_path / "recordings"
    directory.mkdir()
    write(directory / "gx2-a.mcap", [("gx2/76/euler", p) for p in first], cut=40)
    write(directory / "gx2-b.mcap", [("gx2/76/euler", p) for p in second])
    ran = gx2ctl_here("export", str(directory), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran.stderr
    assert "gx2-a.mcap: ends early after" in ran.stderr
    seqs = [int(r["seq"]) for r in rows(tmp_path / "out" / "76_euler.csv")]
    assert seqs == list(range(1, 401)), "lost or reordered rows"


def test_errors_are_one_line_and_exit_2(recording, tmp_path):
    path, _ = recording
    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    for args, words in ((["export", str(tmp_path / "none.mcap"), "--out", str(tmp_path)],
                         "no such file"),
                        (["export", str(text), "--out", str(tmp_path)], "not an MCAP file"),
                        (["plot", str(path), "95"], "no records of node 95"),
                        (["plot", str(path), "76", "--record", "euler"], "no record euler")):
        ran = gx2ctl_here(*args)
        assert ran.status == 2, (args, ran)
        assert words in ran.stderr and len(ran.stderr.strip().splitlines()) == 1, ran.stderr


@pytest.mark.parametrize(("form", "module", "extra"), [("parquet", "pyarrow", "parquet"),
                                                       ("mat", "scipy", "mat"),
                                                       ("ros2", "rosbags", "ros2")])
def test_a_format_without_its_extra_says_how_to_install_it(recording, tmp_path, form,
                                                           module, extra):
    path, _ = recording
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / f"{module}.py").write_text("raise ImportError('not installed')\n")
    env = {**os.environ, "PYTHONPATH": str(shim)}
    main = "import sys; from gateway.ctl.cli import main; sys.exit(main())"
    ran = subprocess.run([sys.executable, "-c", main, "export", str(path),
                          "--out", str(tmp_path / "out"), "--format", form],
                         capture_output=True, text=True, env=env, timeout=60)
    assert ran.returncode == 2, ran
    assert f"pip install 'gx2-gateway[{extra}]'" in ran.stderr
    assert len(ran.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_plot_writes_a_png_with_name_rate_losses_and_gaps(recording, tmp_path):
    path, streamed = recording
    out = tmp_path / "76.png"
    ran = gx2ctl("plot", str(path), "76", "--out", str(out))
    assert ran.status == 0, ran.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000
    image = picture(76, "accel_angrate_mag", streamed, "left-wing")
    # the radio's losses (by the timer) and the gateway's (by seq) apart, each a share
    # of the 200 samples that should have come
    assert image.title == ("left-wing (76): accel_angrate_mag, 100.0 Hz, 195 records\n"
                           "radio: 3 lost (1.50%) · gateway: 2 lost (1.00%)")
    assert [p.title for p in image.panels] == ["accel", "ang rate"]  # mag all NaN: no panel
    assert image.panels[0].unit == "g"
    # the lost samples break the lines: a NaN where they would be
    x = image.x
    gap = next(i for i, v in enumerate(x) if math.isnan(v))
    assert x[gap - 1] == pytest.approx(0.49) and x[gap + 1] == pytest.approx(0.53)
    assert math.isnan(image.panels[0].lines["x"][gap])
    assert sum(math.isnan(v) for v in x) == 2


def test_plot_title_counts_losses_among_all_the_nodes_messages(tmp_path):
    # a poll between two samples of the stream takes a seq: no gap; a message the
    # gateway lost takes one too, and the timer shows the sample missing
    entries, seq = [], 0
    for i in range(100):
        seq += 1
        if i == 40:
            entries.append(("gx2/76/temperatures", payload(
                76, "temperatures", seq, T0 + i / 100 + 0.001, timer=i * 196_608 + 1,
                temperature=(2000, 2100, 2102, 2099))))
            seq += 1
        if i == 70:
            continue  # published as seq 72, lost by the gateway
        entries.append(("gx2/76/euler", payload(76, "euler", seq, T0 + i / 100,
                                                timer=i * 196_608, roll=0.1, pitch=0.2,
                                                yaw=0.3)))
    path = write(tmp_path / "run.mcap", entries)
    found = records_of([path], 76, None, Reading())
    image = picture(76, found.record, found.payloads, found.name, found.marks, found.counts)
    assert image.title.endswith("radio: 0 lost (0.00%) · gateway: 1 lost (1.00%)")
    drawn = gx2ctl_here("plot", str(path), "76", "--out", str(tmp_path / "76.png"))
    assert drawn.status == 0, drawn


def euler_payloads(yaw_degrees: list[float]) -> list[dict]:
    return [payload(77, "euler", i + 1, T0 + i / 100, timer=i * 196_608, roll=0.1,
                    pitch=-0.2, yaw=math.radians(yaw)) for i, yaw in enumerate(yaw_degrees)]


def test_an_angle_that_wraps_is_broken_at_the_wrap_not_drawn_across():
    yaws = [171.0 + 2 * i for i in range(10)]  # 171 .. 189: -179 after 179
    image = picture(77, "euler", euler_payloads([math.remainder(y, 360) for y in yaws]),
                    None)
    [angles] = image.panels
    assert angles.title == "Euler angles" and angles.unit == "deg" and angles.wraps
    yaw, roll = angles.lines["yaw"], angles.lines["roll"]
    assert len(yaw) == len(image.x) == 11  # one point inserted, at the wrap
    wrap = next(i for i, v in enumerate(yaw) if math.isnan(v))
    assert yaw[wrap - 1] == pytest.approx(179) and yaw[wrap + 1] == pytest.approx(-179)
    # x and the angles that do not wrap go on through the inserted point
    assert image.x[wrap] == pytest.approx(0.045) and roll[wrap] == pytest.approx(
        math.degrees(0.1))
    steps = [abs(b - a) for a, b in itertools.pairwise(yaw)
             if not (math.isnan(a) or math.isnan(b))]
    assert max(steps) == pytest.approx(2, abs=1e-3)  # (f32 angles)


def test_an_orientation_matrix_is_drawn_as_angles_with_its_wraps_broken():
    rows = []
    for i in range(20):
        yaw = math.remainder(math.radians(150 + 5 * i), math.tau)
        rows.append(payload(77, "orientation", i + 1, T0 + i / 100, timer=i * 196_608,
                            orientation=nested(matrix_from_euler(0.1, -0.2, yaw))))
    image = picture(77, "orientation", rows, None)
    [angles] = image.panels
    assert angles.unit == "deg" and set(angles.lines) == {"roll", "pitch", "yaw"}
    assert angles.lines["roll"][0] == pytest.approx(math.degrees(0.1))
    assert angles.lines["pitch"][0] == pytest.approx(math.degrees(-0.2))
    assert sum(math.isnan(v) for v in angles.lines["yaw"]) == 1  # the wrap past 180
    assert not any(math.isnan(v) for v in angles.lines["roll"])


STREAMED = [spec for spec in BY_NAME.values() if spec.streamable]


@pytest.mark.parametrize("spec", STREAMED, ids=lambda spec: spec.name)
def test_every_record_a_node_streams_has_a_picture(spec):
    # the records as a 3DM-GX2 (which has a magnetometer) in gx2-sim makes them
    node = SimNode(NodeSettings(76, model=GX2), 0.0)
    rows = []
    for i in range(1, 30):
        record = decode(node.record(spec.code, i / 100)).as_dict()
        values = {k: [list(r) for r in v] if isinstance(v, tuple) and isinstance(
            v[0], tuple) else list(v) if isinstance(v, tuple) else v
                  for k, v in record.items()}
        rows.append({**values, "node": 76, "record": spec.name, "command": spec.code,
                     "seq": i, "host_time": T0 + i / 100, "lqi": 200, "rssi": -50,
                     "device_time": i / 100, "time": T0 + i / 100})
    image = picture(76, spec.name, rows, None)
    drawn = {field for panel in image.panels for field in panel.lines}
    assert image.panels and drawn
    for panel in image.panels:
        for label, values in panel.lines.items():
            assert any(not math.isnan(v) for v in values), (panel.title, label)
    shown = {f.name for f in spec.reply} - {"timer"}
    titles = " ".join(panel.title for panel in image.panels).replace(" ", "_")
    assert all(name in titles or name in drawn for name in shown), (shown, titles)
    figure = figure_of(image)
    assert len([axis for axis in figure.axes if axis.lines]) == len(image.panels)
    pyplot.close(figure)


def test_the_legends_are_off_the_data():
    image = picture(77, "euler_angrate", [
        payload(77, "euler_angrate", i + 1, T0 + i / 100, timer=i * 196_608, roll=0.1,
                pitch=-0.2, yaw=0.01 * i, ang_rate=(0.0, 0.0, 0.2)) for i in range(50)], None)
    figure = figure_of(image)
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    axes = [axis for axis in figure.axes if axis.get_legend() is not None]
    assert len(axes) == 2
    for axis in axes:
        legend = axis.get_legend().get_window_extent(renderer)
        inside = axis.get_window_extent(renderer)
        assert legend.x0 >= inside.x1, (legend, inside)  # to its right, not over it
        assert legend.x1 <= figure.bbox.x1  # and in the picture


def test_a_record_with_nothing_to_draw_is_refused_in_one_line(tmp_path):
    # an Inertia-Link's magnetometer: NaN in every sample
    path = write(tmp_path / "run.mcap", [("gx2/95/mag", payload(
        95, "mag", i + 1, T0 + i / 100, timer=i * 196_608, mag=(NAN,) * 3))
        for i in range(20)])
    ran = gx2ctl_here("plot", str(path), "95", "--out", str(tmp_path / "95.png"))
    assert ran.status == 2, ran
    assert "no values to draw" in ran.stderr and len(ran.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "95.png").exists()


LONG_LABEL = "tap 2 with a rather long label to see how it is drawn on the plot"


def panels_with_marks(texts: list[tuple[float, str]]) -> tuple[list, list]:
    """The panels' window extents, and (text, its extent, its panel's) of each mark, of
    node 77's euler_angrate plot (two panels) with marks ``texts`` at (s, text)."""
    rows = [payload(77, "euler_angrate", i + 1, T0 + i / 100, timer=i * 196_608, roll=0.1,
                    pitch=-0.2, yaw=0.01 * i, ang_rate=(0.0, 0.0, 0.2)) for i in range(500)]
    marks = [Mark(T0 + at, T0 + at, (77,), text) for at, text in texts]
    figure = figure_of(picture(77, "euler_angrate", rows, None, marks))
    figure.canvas.draw()  # (as savefig does: the layout is done again)
    renderer = figure.canvas.get_renderer()
    panels = [axis.get_window_extent(renderer) for axis in figure.axes if axis.lines]
    labels = [(text.get_text(), text.get_window_extent(renderer),
               axis.get_window_extent(renderer)) for axis in figure.axes
              for text in axis.texts]
    pyplot.close(figure)
    return panels, labels


def test_a_long_mark_label_stays_inside_its_panel_and_leaves_the_panels_alone():
    plain, _ = panels_with_marks([])
    panels, labels = panels_with_marks([(0.5, "start"), (2.5, LONG_LABEL),
                                        (4.9, LONG_LABEL)])
    assert [v for p in panels for v in (p.y0, p.y1, p.x0)] == pytest.approx(
        [v for p in plain for v in (p.y0, p.y1, p.x0)])  # not squashed, y labels not cut
    assert panels[0].height == pytest.approx(panels[1].height)
    assert [text for text, _, _ in labels] == ["start", *[labels[1][0]] * 2]
    shortened = labels[1][0]
    assert shortened.endswith("\u2026") and LONG_LABEL.startswith(shortened[:-1])
    assert len(shortened) > 20  # as much as fits, not cut to nothing
    for text, extent, inside in labels:
        assert inside.x0 <= extent.x0 and extent.x1 <= inside.x1, text
        assert inside.y0 <= extent.y0 and extent.y1 <= inside.y1, text


def test_a_status_that_is_not_a_json_object_is_passed_over_by_export(tmp_path):
    # export reads the statuses for when a base station was down; a foreign one (a JSON
    # list, written by another tool) tells nothing and costs no row
    path = tmp_path / "odd.mcap"
    with path.open("wb") as output:
        writer = Writer(output)
        writer.start(profile="", library="another tool")
        status = writer.register_channel("gx2/gateway/status", "json", 0)
        euler = writer.register_channel("gx2/76/euler", "json", 0)
        writer.add_message(status, int(T0 * 1e9), b"[1, 2]", int(T0 * 1e9), 1)
        for i in range(50):
            record = payload(76, "euler", i + 1, T0 + i / 100, timer=i, roll=0.1,
                             pitch=0.2, yaw=0.3)
            when = int(record["host_time"] * 1e9)
            writer.add_message(euler, when, json.dumps(record).encode(), when, i + 2)
        writer.finish()
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran.stderr
    assert len(rows(tmp_path / "out" / "76_euler.csv")) == 50


def test_a_record_this_version_does_not_know_exports_typed_and_named_for_matlab(tmp_path):
    """Its fields typed by their first value, its names made MATLAB's."""
    foreign = {"node": 76, "record": "custom", "seq": 1, "host_time": T0, "lqi": 9,
               "rssi": -40, "2nd-value": 7, "label": "left"}
    path = write(tmp_path / "foreign.mcap", [("gx2/76/custom", foreign),
                                             ("gx2/76/custom", {**foreign, "seq": 2,
                                                                "2nd-value": 7.5})])
    for form in ("parquet", "mat"):
        ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / form), "--format", form)
        assert ran.status == 0, ran.stderr
    table = pq.read_table(tmp_path / "parquet" / "76_custom.parquet")
    assert table.schema.field("2nd-value").type == pa.float64()
    assert table.schema.field("label").type == pa.string()
    assert table.to_pydict()["2nd-value"] == [7.0, 7.5]
    struct = loadmat(tmp_path / "mat" / "76_custom.mat", simplify_cells=True)["n76_custom"]
    assert struct["f2nd_value"].tolist() == [7.0, 7.5]
    assert struct["label"].tolist() == ["left", "left"]
    assert struct["units"]["rssi"] == "dBm"


def test_a_mark_whose_time_no_float_holds_exports_at_its_recorded_time(tmp_path):
    """A foreign recording's mark with ``time`` 10**400 (valid JSON, no float holds it)
    is exported at the time its message was recorded, not a traceback."""
    mark = {"text": "start", "time": 10**400, "host_time": T0 + 0.5, "nodes": []}
    path = write(tmp_path / "marks.mcap", [("gx2/gateway/mark", mark)])
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"))
    assert ran.status == 0, ran.stderr
    with (tmp_path / "out" / "marks.csv").open() as table:
        (row,) = list(csv.DictReader(table))
    assert row["text"] == "start" and float(row["host_time"]) == T0 + 0.5
    assert math.isfinite(float(row["time"]))


def test_close_marks_labels_are_set_side_by_side_not_over_each_other():
    """Marks closer than a label's width (a knock just after a trial's start): their
    labels apart, in the marks' order, on both halves of the plot (issue 43: drawn
    over each other)."""
    texts = [(1.0, "start"), (1.01, "knock"), (1.02, "again"),
             (4.0, "halt"), (4.01, "stop")]
    _, labels = panels_with_marks(texts)
    assert [text for text, _, _ in labels] == [text for _, text in texts]
    for side in (labels[:3], labels[3:]):
        extents = sorted((extent for _, extent, _ in side), key=lambda e: e.x0)
        for one, other in itertools.pairwise(extents):
            assert one.x1 <= other.x0, (one, other)
    assert labels[0][1].x0 < labels[1][1].x0 < labels[2][1].x0  # in the marks' order
    assert labels[3][1].x0 < labels[4][1].x0
