"""gx2ctl export and plot, run as users run them, on recordings written through the
recording writer from payloads shaped as the gateway publishes them."""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from aspp.records import decode, encode
from gateway.recording.files import RecordingWriter
from gateway.recording.plot import picture
from tests.helpers.processes import gx2ctl

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
    """Node 76 at 100 Hz with a seq gap and a time gap; node 77's orientation matrix;
    a magnetometer of NaN; an untimed record; the status naming node 76."""
    entries: list[tuple[str, dict]] = [("gx2/gateway/status", {
        "gateway": {"time": T0}, "nodes": [{"node": 76, "name": "left-wing"}]})]
    streamed = []
    seq = 0
    for i in range(200):
        if i in (50, 51, 52):
            continue  # lost: seq and time both skip
        seq = i + 1
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
        "76_accel_angrate_mag.csv", "76_firmware_version.csv", "77_orientation.csv"]
    table = rows(out / "76_accel_angrate_mag.csv")
    with (out / "76_accel_angrate_mag.csv").open() as file:
        header = file.readline().strip().split(",")
    assert header == ["time", "host_time", "device_time", "seq", "lqi", "rssi",
                      "accel_x", "accel_y", "accel_z", "ang_rate_x", "ang_rate_y",
                      "ang_rate_z", "mag_x", "mag_y", "mag_z", "timer"]
    assert len(table) == len(streamed) == 197
    for row, sent in zip(table, streamed, strict=True):
        assert float(row["time"]) == sent["time"]
        assert float(row["host_time"]) == sent["host_time"]
        assert int(row["seq"]) == sent["seq"] and int(row["timer"]) == sent["timer"]
        assert [float(row[f"accel_{a}"]) for a in "xyz"] == sent["accel"]
        assert row["mag_x"] == row["mag_y"] == row["mag_z"] == ""  # NaN
    [matrix] = rows(out / "77_orientation.csv")
    assert [float(matrix[f"orientation_{r}{c}"]) for r in (1, 2, 3) for c in (1, 2, 3)] == [
        1.0, 0.0, 0.0, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5]
    [untimed] = rows(out / "76_firmware_version.csv")
    assert untimed["time"] == untimed["device_time"] == "" and untimed["version"] == "2104"
    assert "197 rows" in ran.stdout


def test_export_parquet_has_the_same_table(recording, tmp_path):
    path, streamed = recording
    ran = gx2ctl("export", str(path), "--out", str(tmp_path), "--format", "parquet")
    assert ran.status == 0, ran.stderr
    table = pq.read_table(tmp_path / "76_accel_angrate_mag.parquet").to_pydict()
    assert list(table)[:8] == ["time", "host_time", "device_time", "seq", "lqi", "rssi",
                               "accel_x", "accel_y"]
    assert table["seq"] == [p["seq"] for p in streamed]
    assert table["accel_x"] == [p["accel"][0] for p in streamed]
    assert table["mag_z"] == [None] * len(streamed)


def test_a_file_cut_short_and_several_files_export_in_order(tmp_path):
    first = [payload(76, "euler", i + 1, T0 + i / 100, timer=i, roll=0.1, pitch=0.2,
                     yaw=0.3) for i in range(300)]
    second = [payload(76, "euler", i + 301, T0 + 3 + i / 100, timer=300 + i, roll=0.1,
                      pitch=0.2, yaw=0.3) for i in range(100)]
    directory = tmp_path / "recordings"
    directory.mkdir()
    write(directory / "gx2-a.mcap", [("gx2/76/euler", p) for p in first], cut=40)
    write(directory / "gx2-b.mcap", [("gx2/76/euler", p) for p in second])
    ran = gx2ctl("export", str(directory), "--out", str(tmp_path / "out"))
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
        ran = gx2ctl(*args)
        assert ran.status == 2, (args, ran)
        assert words in ran.stderr and len(ran.stderr.strip().splitlines()) == 1, ran.stderr


def test_parquet_without_pyarrow_says_how_to_install_it(recording, tmp_path):
    path, _ = recording
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "pyarrow.py").write_text("raise ImportError('not installed')\n")
    env = {**os.environ, "PYTHONPATH": str(shim)}
    main = "import sys; from gateway.ctl.cli import main; sys.exit(main())"
    ran = subprocess.run([sys.executable, "-c", main, "export", str(path),
                          "--out", str(tmp_path / "out"), "--format", "parquet"],
                         capture_output=True, text=True, env=env, timeout=60)
    assert ran.returncode == 2, ran
    assert "pip install 'gx2-gateway[parquet]'" in ran.stderr
    assert len(ran.stderr.strip().splitlines()) == 1


def test_plot_writes_a_png_with_name_rate_losses_and_gaps(recording, tmp_path):
    path, streamed = recording
    out = tmp_path / "76.png"
    ran = gx2ctl("plot", str(path), "76", "--out", str(out))
    assert ran.status == 0, ran.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000
    image = picture(76, "accel_angrate_mag", streamed, "left-wing")
    assert image.title.startswith("left-wing (76): accel_angrate_mag, 100.0 Hz, 3 lost")
    assert [p.title for p in image.panels] == ["accel", "ang rate"]  # mag all NaN: no panel
    assert image.panels[0].unit == "g"
    # the three lost samples break the lines: a NaN where they would be
    x = image.x
    gap = next(i for i, v in enumerate(x) if math.isnan(v))
    assert x[gap - 1] == pytest.approx(0.49) and x[gap + 1] == pytest.approx(0.53)
    assert math.isnan(image.panels[0].lines["x"][gap])
