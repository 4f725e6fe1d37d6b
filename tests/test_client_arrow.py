"""gateway.client's ``Recording.to_arrow()``: to_pandas's rows and columns, in export's
Arrow types, times to the ns; held against to_pandas, and against the recordings read
by the ``mcap`` package; what its one-call path cannot take, taken as the iteration
takes it; without pyarrow, one line saying how to install it (issue 44)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pytest

from gateway.client import Recording
from gateway.recording.columns import nanoseconds
from gateway.recording.writer import RecordingWriter
from tests.helpers.recorded import T0, hourly_files
from tests.recording.test_refined import written
from tests.test_client_recorded import DOC, payload, recorded, said_without

TEXT = pa.dictionary(pa.int32(), pa.string())


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    return hourly_files(tmp_path)


def _values(frame: pd.DataFrame) -> dict[str, list]:
    """Each column's values as Python's (NaN and NaT as None, a category as its text,
    a timestamp as its ns), to hold two frames' values against each other."""
    def value(v: object) -> object:
        if v is None or v is pd.NaT or (isinstance(v, float) and math.isnan(v)):
            return None
        return v.value if isinstance(v, (pd.Timestamp, pd.Timedelta)) else v
    return {name: [value(v) for v in frame[name].astype(object)] for name in frame.columns}


def _same_as_to_pandas(make) -> pa.Table:
    """``make()``'s Recording, to_arrow against to_pandas (and what each counted)."""
    arrow, frames = make(), make()
    table, frame = arrow.to_arrow(), frames.to_pandas()
    assert table.column_names == list(frame.columns)
    assert _values(table.to_pandas()) == _values(frame)
    assert (arrow.lost, arrow.duplicates, arrow.malformed) == (
        frames.lost, frames.duplicates, frames.malformed)
    return table


@pytest.mark.parametrize("asked", [{}, {"nodes": [11], "between_marks": ("start", "stop")},
                                   {"records": ["euler"], "start": "10", "stop": "45"}],
                         ids=["all", "trials", "one-record"])
def test_to_arrow_is_to_pandas_in_export_types(recordings: Path, asked: dict) -> None:
    # (each file given twice: its messages once)
    table = _same_as_to_pandas(lambda: Recording([recordings, recordings], **asked))
    types = {field.name: field.type for field in table.schema}
    assert types["time"] == types["host_time"] == pa.timestamp("ns", tz="UTC")
    assert types["device_time"] == pa.duration("ns")
    assert (types["gateway"], types["record"], types["node"], types["gap"]) == (
        TEXT, TEXT, pa.int64(), pa.int64())
    assert (types["lqi"], types["rssi"]) == (pa.uint8(), pa.int8())
    assert table.schema.field("time").metadata[b"unit"] == b"s"


def test_to_arrow_holds_what_the_mcap_package_reads(recordings: Path) -> None:
    table = Recording(recordings).to_arrow()
    wanted = [(t, p) for t, p in recorded(recordings, 0, 2 ** 32)
              if t.split("/")[1].isdigit()]
    assert table.num_rows == len(wanted)
    assert table["record"].to_pylist() == [t.split("/")[2] for t, _ in wanted]
    assert table["node"].to_pylist() == [int(t.split("/")[1]) for t, _ in wanted]
    assert table["seq"].to_pylist() == [p["seq"] for _, p in wanted]
    for name in ("time", "host_time", "device_time"):  # to the ns the message wrote
        assert table[name].cast(pa.int64()).to_pylist() == [
            nanoseconds(p.get(name)) for _, p in wanted], name
    assert table["ang_rate_z"].to_pylist() == [
        p["ang_rate"][2] if "ang_rate" in p else None for _, p in wanted]
    assert table["yaw"].to_pylist() == [p.get("yaw") for _, p in wanted]


def test_what_the_one_call_path_cannot_take_is_taken_as_the_iteration_takes_it(
        tmp_path: Path) -> None:
    """A message that is not a JSON object (a topic's first too) and one without a seq
    (skipped, counted);
    a record left out taking a seq (no gap), a gap, a restart; NaN (null in the file);
    an untimed reply among timed records (times exact, its null); an orientation of a
    file of before the matrix's derived fields (derived)."""
    path = tmp_path / "run.mcap"
    turned = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # yaw of 90 degrees
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        for i, seq in enumerate([1, 2, 3, 4, 5, 8, 9, 2, 3]):
            record = "temperatures" if seq == 3 and i == 2 else "accel_angrate_mag"
            writer.message(f"gx2/76/{record}", payload(i + 1, seq, record))
        writer.message("gx2/76/temperatures", {}, b"[1, 2]", (T0 + 1, T0 + 1))
        writer.message("gx2/78/euler", {}, b"nonsense", (T0 + 1, T0 + 1))  # (its first)
        writer.message("gx2/78/euler", {"node": 78, "record": "euler", "seq": 1,
                                        "host_time": T0 + 1, "roll": 0.5})
        writer.message("gx2/76/accel_angrate_mag", payload(20, 4) | {"seq": None})
        writer.message("gx2/76/eeprom_read", {
            "node": 76, "record": "eeprom_read", "command": 0xE5, "seq": 4,
            "host_time": T0 + 0.2, "lqi": 200, "rssi": -50, "address": 0xFCA2,
            "value": 512})
        for seq in (5, 6):
            writer.message("gx2/77/orientation", {
                "node": 77, "record": "orientation", "command": 0xC5, "seq": seq,
                "host_time": T0 + seq / 100, "time": T0 + seq / 100 + 0.000123457,
                "device_time": seq / 100 + 1e-9, "lqi": 200, "rssi": -50,
                "timer": seq * 1966, "orientation": turned})
        writer.finish()
    table = _same_as_to_pandas(lambda: Recording(path, records=[
        "accel_angrate_mag", "eeprom_read", "orientation", "euler"]))
    one = Recording(path, nodes=[76], records=["accel_angrate_mag"])
    rows = one.to_arrow()
    assert rows["seq"].to_pylist() == [1, 2, 4, 5, 8, 9, 2, 3]
    assert rows["gap"].to_pylist() == [0, 0, 0, 0, 2, 0, 0, 0]
    assert rows["restarted"].to_pylist() == [False] * 6 + [True, False]
    assert one.malformed == 2 and one.lost == {(str(path), 76): 2}  # ([1, 2], no seq)
    assert rows["mag_x"].null_count == rows.num_rows
    untimed = table.filter(pa.compute.equal(table["record"].cast(pa.string()), "eeprom_read"))
    assert untimed["time"].to_pylist() == [None] and untimed["value"].to_pylist() == [512]
    assert untimed["host_time"].cast(pa.int64()).to_pylist() == [nanoseconds(T0 + 0.2)]
    oriented = table.filter(pa.compute.equal(table["node"], 77))
    assert oriented["yaw"].to_pylist() == pytest.approx([math.pi / 2] * 2)
    assert oriented["time"].cast(pa.int64()).to_pylist() == [
        nanoseconds(T0 + seq / 100 + 0.000123457) for seq in (5, 6)]


def test_a_refined_time_is_to_pandas_s_with_its_two_columns(tmp_path: Path) -> None:
    """``time="refined"``: the refined times, to the ns, and how each was placed, after
    ``time`` as to_pandas has them (the refinement is the loop's)."""
    path = written(tmp_path / "line.mcap")
    table = _same_as_to_pandas(lambda: Recording(path, time="refined"))
    assert table.column_names[6:9] == ["time", "time_placed", "time_bound_ms"]
    assert (table.schema.field("time_placed").type, table.schema.field(
        "time_bound_ms").type) == (pa.string(), pa.float64())
    looped = [m for m in Recording(path, time="refined")]
    assert table["time"].cast(pa.int64()).to_pylist() == [nanoseconds(m.time)
                                                          for m in looped]
    assert table["time_placed"].to_pylist() == [m["time_placed"] for m in looped]
    assert set(table["time_placed"].to_pylist()) == {"live", "unplaceable", None}


def test_an_empty_window_is_to_pandas_columns(recordings: Path) -> None:
    table = _same_as_to_pandas(lambda: Recording(recordings, records=["euler"],
                                                 start="1.01", stop="1.1"))
    assert table.num_rows == 0 and table.schema.field("time").type == pa.timestamp(
        "ns", tz="UTC")


def test_to_arrow_without_pyarrow_says_how_to_install_it(recordings: Path) -> None:
    assert said_without("pyarrow", recordings, "to_arrow") == \
        "to_arrow needs pyarrow: pip install 'gx2-gateway[arrow]'\n"


def test_the_docs_arrow_example_runs_as_written(recordings: Path, capsys) -> None:
    """docs/subscribing.md's Arrow example, its recordings and nodes the test's: the
    second trial's rows, queried by DuckDB in place."""
    [code] = [b for b in re.findall(r"```python\n(.*?)```", DOC.read_text(), re.DOTALL)
              if ".to_arrow()" in b]
    names: dict = {}
    exec(code.replace('"recordings/"', repr(str(recordings))).replace(
        "nodes=[76, 77]", "nodes=[11, 12]"), names)
    trial = Recording(recordings, nodes=[11, 12], between_marks=("start", "stop"), trial=2)
    assert names["rows"].num_rows == len(trial.to_pandas()) == 2 * (20 * 25 + 1)
    assert "count_star()" in capsys.readouterr().out
