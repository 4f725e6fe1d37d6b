"""A Parquet export a batch at a time (:mod:`gateway.recording.columnexport`) against
the row by row export it stands in for: the same files, byte for byte in their values
and schemas, and the same losses, for recordings that exercise what the batches must
hand to the row path or to the streams between batches (a damaged chunk, a
continuous-mode reply, a station's outage, values of the wrong type, lists of another
length, records without a device time, times beyond what a timestamp holds)."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.io import loadmat

from gateway.recording import columnexport, export
from gateway.recording.reports import Reading
from gateway.recording.writer import RecordingWriter
from tests.helpers.recorded import foreign_file, make_file

T0 = 1_795_000_000.0


def _both(paths: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
          form: str = "parquet") -> int:
    """Export ``paths`` both ways; the rows, having held them equal (a CSV file byte for
    byte, a .mat file's every field)."""
    with monkeypatch.context() as patched:
        patched.setattr(export, "SMALL", 0)  # (these recordings are small)
        batch = export.export(paths, tmp_path / f"batch-{form}", Reading(), form)
    with monkeypatch.context() as patched:
        patched.setattr(columnexport, "BATCH_WRITERS", {})
        rows = export.export(paths, tmp_path / f"rows-{form}", Reading(), form)
    assert batch[1] == rows[1]
    assert [p.name for p, _ in batch[0]] == [p.name for p, _ in rows[0]]
    total = 0
    for (one, a), (other, b) in zip(batch[0], rows[0], strict=True):
        assert vars(a.losses) == vars(b.losses), one.name
        total += a.rows
        if form == "csv":
            assert one.read_bytes() == other.read_bytes(), one.name
        elif form == "mat":
            x, y = loadmat(one), loadmat(other)
            assert _plain(x) == _plain(y), one.name
        else:
            x, y = pq.read_table(one), pq.read_table(other)
            assert x.schema.equals(y.schema, check_metadata=True), one.name
            assert x.to_pylist() == y.to_pylist(), one.name
    return total


def _plain(value: object) -> object:
    """A .mat file's content as Python values (NaN as None), to compare."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items() if not k.startswith("__")}
    if isinstance(value, np.ndarray):
        if value.dtype.names:
            return {field: _plain(value[field][0, 0]) for field in value.dtype.names}
        if value.dtype.kind == "O":
            return [_plain(item) for item in value.ravel()]
        if value.dtype.kind == "f":
            return [None if v != v else v for v in value.ravel().tolist()]
        return value.ravel().tolist()
    return value


def _stream(writer: RecordingWriter, node: int, count: int, lose: float, seed: int,
            start: int = 0, reboot_at: int | None = None) -> None:
    chance = random.Random(seed)
    seq = 0
    for i in range(start, start + count):
        timer_i = i - (reboot_at or 0) if reboot_at is not None and i >= reboot_at else i
        seq += 1
        if chance.random() < lose:
            continue
        at = T0 + i / 100
        writer.message(f"gx2/{node}/accel_angrate", {
            "node": node, "record": "accel_angrate", "command": 0xC2, "seq": seq,
            "host_time": at + 0.004, "time": at, "device_time": i / 100,
            "timer": timer_i * 196_608, "lqi": 200, "rssi": -50,
            "accel": [0.001 * i, 0.5, -1.0], "ang_rate": [0.1, None, 0.3]})


def test_streams_with_losses_reboots_and_replies(tmp_path, monkeypatch) -> None:
    path = tmp_path / "run.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        _stream(writer, 76, 25_000, 0.1, 1, reboot_at=12_000)
        _stream(writer, 77, 3_000, 0.3, 2)
        writer.message("gx2/gateway/status", {"gateway": {"time": T0 + 300},
                                              "link": {"state": "down", "since": T0 + 300},
                                              "nodes": [{"node": 77}]})
        writer.message("gx2/gateway/status", {"gateway": {"time": T0 + 302},
                                              "link": {"state": "up", "since": T0 + 302},
                                              "nodes": [{"node": 77}]})
        writer.message("gx2/77/continuous_mode", {
            "node": 77, "record": "continuous_mode", "command": 0xC4, "seq": 4000,
            "host_time": T0 + 310, "device_time": 310.0, "timer": 31_000 * 196_608})
        _stream(writer, 77, 2_000, 0.05, 3, start=31_100)
        writer.finish()
    assert _both([path], tmp_path, monkeypatch) > 25_000


def test_recordings_damaged_cut_and_odd(tmp_path, monkeypatch) -> None:
    whole = make_file(tmp_path / "a.mcap", 0, 30)
    cut = make_file(tmp_path / "b.mcap", 30, 20, finish=False)
    damaged = tmp_path / "c.mcap"
    data = bytearray(make_file(tmp_path / "c0.mcap", 50, 20).read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = bytes(64)  # (a chunk's content)
    damaged.write_bytes(bytes(data))
    euler = {"node": 11, "record": "euler", "command": 0xCE, "host_time": T0,
             "roll": 0.1, "pitch": 0.2, "yaw": 0.3, "device_time": 1.0, "timer": 0}
    odd = foreign_file(tmp_path / "odd.mcap", [
        ("gx2/11/euler", {**euler, "seq": 1, "time": T0 + 1.5e-7}),
        ("gx2/11/euler", {**euler, "seq": 2, "roll": True, "host_time": T0 + 1}),
        ("gx2/11/euler", {**euler, "seq": 3, "time": 1e10, "host_time": T0 + 2}),
        ("gx2/11/euler", {**euler, "seq": 4, "pitch": "up", "host_time": T0 + 3}),
        ("gx2/11/euler", {**euler, "seq": 5, "device_time": None, "host_time": T0 + 4}),
        ("gx2/12/accel_angrate", {"node": 12, "record": "accel_angrate", "seq": 1,
                                  "host_time": T0, "accel": [1.0, 2.0],
                                  "ang_rate": [0.1, 0.2, 0.3, 0.4], "lqi": 300}),
        ("gx2/13/custom", {"node": 13, "record": "custom", "seq": 1, "host_time": T0,
                           "odd": [1, 2], "label": "x", "value": 10 ** 30})])
    assert _both([whole, cut, damaged, odd], tmp_path, monkeypatch) > 2_000


def _odd_values(path: Path) -> Path:
    """Values a column cannot tell as the row path writes them: whole floats, an
    integer among floats, tiny and huge floats, an integer past any double, texts that
    need quoting in CSV, a bool, nulls, a number where a text was."""
    euler = {"node": 11, "record": "euler", "command": 0xCE, "roll": 0.1, "pitch": -1.0,
             "yaw": 0.0, "timer": 0}
    custom = {"node": 13, "record": "custom", "label": "a, b", "value": 1.5}
    entries = []
    for seq in range(1, 301):
        at = T0 + seq / 100
        entries.append(("gx2/11/euler", {**euler, "seq": seq, "host_time": at,
                                         "device_time": seq / 100, "time": at,
                                         "roll": [0.1, 1e-05, 1e17, 1.0, 2.5e-300][seq % 5],
                                         "yaw": 10 ** 400 if seq == 77 else 0.0}))
        if seq == 150:
            entries.append(("gx2/11/euler", {**euler, "seq": 1000, "host_time": at,
                                             "device_time": 99, "yaw": 3}))
        entries.append(("gx2/13/custom", {**custom, "seq": seq, "host_time": at,
                                          "label": ['a, b', 'say "hi"', "two\nlines", None,
                                                    "plain"][seq % 5],
                                          "value": [1.5, 2, None, True, 7.0][seq % 5]}))
    entries.append(("gx2/13/custom", {**custom, "seq": 301, "host_time": T0 + 4,
                                      "label": 12.0}))
    return foreign_file(path, entries)


@pytest.mark.parametrize("form", ["csv", "mat", "parquet"])
def test_each_format_a_batch_at_a_time_as_row_by_row(tmp_path, monkeypatch, form) -> None:
    path = tmp_path / "run.mcap"
    with path.open("wb") as output:
        writer = RecordingWriter(output)
        _stream(writer, 76, 12_000, 0.1, 1, reboot_at=6_000)
        _stream(writer, 77, 3_000, 0.3, 2)
        writer.finish()
    damaged = tmp_path / "c.mcap"
    data = bytearray(make_file(tmp_path / "c0.mcap", 50, 20).read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = bytes(64)
    damaged.write_bytes(bytes(data))
    assert _both([path, damaged, _odd_values(tmp_path / "odd.mcap")], tmp_path, monkeypatch,
                 form) > 12_000


_IMPORTS = """
import sys
from pathlib import Path
if len(sys.argv) > 4:  # (modules not installed: an import of them fails)
    class Missing:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in sys.argv[4:]:
                raise ImportError(f"no module named {name!r}")
    sys.meta_path.insert(0, Missing())
from gateway.recording.export import export
from gateway.recording.reports import Reading
export([Path(sys.argv[1])], Path(sys.argv[2]), Reading(), sys.argv[3])
print(" ".join(sorted(m for m in ("pyarrow", "pandas") if m in sys.modules)))
"""


@pytest.mark.parametrize("form", ["csv", "mat"])
def test_a_small_export_goes_row_by_row_without_importing_pyarrow(tmp_path, form) -> None:
    """A recording under export.SMALL to CSV or .mat: pyarrow's import (and pandas'
    through it) would cost more than the batches save (0.25 s of CPU against 0.55 s for
    20 s of recording). One past it goes a batch at a time."""
    import subprocess
    import sys
    small = make_file(tmp_path / "gx2-20261120T000000.000Z.mcap", 0, 20)
    assert small.stat().st_size < export.SMALL
    large = tmp_path / "large" / "gx2-20261120T000000.000Z.mcap"
    large.parent.mkdir()
    with large.open("wb") as out:
        writer = RecordingWriter(out)
        _stream(writer, 76, 30_000, 0.0, 1)
        writer.finish()
    assert large.stat().st_size >= export.SMALL
    imported = {}
    for name, path in (("small", small), ("large", large)):
        ran = subprocess.run([sys.executable, "-c", _IMPORTS, str(path),
                              str(tmp_path / f"out-{name}"), form],
                             capture_output=True, text=True, timeout=120,
                             cwd=Path(__file__).resolve().parents[2])
        assert ran.returncode == 0, ran.stderr
        imported[name] = ran.stdout.split()
    assert "pyarrow" not in imported["small"], imported
    assert "pyarrow" in imported["large"], imported


def test_a_csv_export_without_pyarrow_or_numpy_goes_row_by_row(tmp_path) -> None:
    """Neither is a dependency of the gateway's own: CSV is written without them, the
    same file as with them."""
    import subprocess
    import sys
    large = tmp_path / "gx2-20261120T000000.000Z.mcap"
    with large.open("wb") as out:
        writer = RecordingWriter(out)
        _stream(writer, 76, 30_000, 0.01, 2)
        writer.finish()
    assert large.stat().st_size >= export.SMALL
    for name, missing in (("with", []), ("without", ["pyarrow", "numpy", "pandas"])):
        ran = subprocess.run([sys.executable, "-c", _IMPORTS, str(large),
                              str(tmp_path / name), "csv", *missing],
                             capture_output=True, text=True, timeout=120,
                             cwd=Path(__file__).resolve().parents[2])
        assert ran.returncode == 0, ran.stderr
        assert ("pyarrow" in ran.stdout.split()) == (name == "with"), ran.stdout
    written = sorted(path.name for path in (tmp_path / "without").glob("*.csv"))
    assert "76_accel_angrate.csv" in written
    for name in written:
        assert (tmp_path / "without" / name).read_bytes() == \
            (tmp_path / "with" / name).read_bytes(), name
