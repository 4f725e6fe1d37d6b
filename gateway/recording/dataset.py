"""Recordings as a Parquet dataset (``gx2ctl dataset RECORDINGS OUT``), partitioned
Hive-style as DuckDB, Polars, Spark, Trino and Athena read it as it is:
``OUT/record=<record>/node=<address>/date=<YYYY-MM-DD>/part-<file>.parquet``, the
columns and types of ``export --format parquet`` (:mod:`.columnexport`), a part per
recording, node, record and UTC day of its rows' ``time``; and ``OUT/trials.parquet``,
the trials the marks define (:mod:`.trials`), made again each run.

Incremental and idempotent: ``OUT/_converted.json`` names each recording converted
(its size and modification time); a run converts only the finished recordings not in
it, or changed since (their old parts replaced), so a timer running it keeps the
dataset minutes behind the recorder. Every part is written in the hidden work folder
and renamed into its partition when whole: a partition's folder holds nothing but whole
parts, even after a run killed half way (a Polars scan of a folder reads every file in
it, hidden or not; tests/recording/test_dataset_killed.py). The list of what was
converted is replaced after each recording. A recording gone (retention, a move)
leaves its parts: the dataset is never trimmed by what the recorder deletes.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .catalogue import Described, catalogue
from .columnexport import export_batches
from .columns import nanoseconds
from .parquetfile import parquet_modules
from .reports import Reading
from .tables import TEMPORARY
from .trials import listed
from .window import _marks

CONVERTED = "_converted.json"
TRIALS = "trials.parquet"
WORK = ".converting"
"""Where a recording's tables are exported before they are parted (hidden: no query's
glob takes it)."""


@dataclass
class Converted:
    """What a run did."""

    files: list[tuple[Path, int]]
    """Each recording converted, and its rows."""
    current: int
    """Recordings converted by an earlier run and unchanged."""
    writing: list[Path]
    """Recordings a writer still has open: converted by a later run."""
    trials: int


def convert(paths: list[Path], out: Path, reading: Reading,
            said: Callable[[str], None] = lambda line: None) -> Converted:
    """Convert the recordings ``paths`` not yet converted into the dataset ``out``."""
    pa, pq = parquet_modules()
    out.mkdir(parents=True, exist_ok=True)
    done = _load(out / CONVERTED)
    files = catalogue(paths, read_writing=False)
    result = Converted([], 0, [], 0)
    for described in files:
        key, stamp = described.path.name, _stamp(described.path)
        if described.writing:
            result.writing.append(described.path)
            continue
        if done.get(key) == stamp:
            result.current += 1
            continue
        rows = _convert_one(described, out, reading, pq)
        done[key] = stamp
        _save(out / CONVERTED, done)
        result.files.append((described.path, rows))
        said(f"{described.path}  {rows:,} rows")
    result.trials = _trials(files, out, pa, pq)
    return result


def _stamp(path: Path) -> dict[str, int]:
    status = path.stat()
    return {"bytes": status.st_size, "mtime_ns": status.st_mtime_ns}


def _load(path: Path) -> dict[str, Any]:
    try:
        loaded = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return loaded if isinstance(loaded, dict) else {}


def _save(path: Path, done: dict[str, Any]) -> None:
    hidden = path.with_name(TEMPORARY.format(name=path.name))
    hidden.write_text(json.dumps(done, indent=1, sort_keys=True), encoding="utf-8")
    os.replace(hidden, path)


def _convert_one(described: Described, out: Path, reading: Reading, pq: Any) -> int:
    """One recording's tables exported, then parted by day: its rows."""
    work = out / WORK / described.path.stem
    shutil.rmtree(work, ignore_errors=True)
    try:
        tables, _ = export_batches([described.path], work, reading, "parquet")
        part = f"part-{described.path.stem}.parquet"
        for stale in out.glob(f"record=*/node=*/date=*/{part}"):
            stale.unlink()  # (a recording changed since: its parts made again)
        rows = 0
        for path, table in tables:
            rows += _parted(pq.read_table(path), out, work, table.record, table.node,
                            part, pq)
        return rows
    finally:
        shutil.rmtree(work, ignore_errors=True)
        with contextlib.suppress(OSError):
            (out / WORK).rmdir()


def _parted(table: Any, out: Path, work: Path, record: str, node: int, part: str,
            pq: Any) -> int:
    """A table's rows written to the day partitions of their time (else host_time),
    each day's part made in ``work`` (on the dataset's file system) and renamed there."""
    import pyarrow.compute as pc
    when = pc.coalesce(table.column("time"), table.column("host_time"))
    days = pc.strftime(when, format="%Y-%m-%d")
    for day in pc.unique(days).to_pylist():
        rows = table.filter(pc.is_null(days) if day is None else pc.equal(days, day))
        folder = out / f"record={record}" / f"node={node}" / f"date={day or 'unknown'}"
        hidden = work / TEMPORARY.format(name=f"{record}.{node}.{day}.{part}")
        pq.write_table(rows, hidden)
        folder.mkdir(parents=True, exist_ok=True)
        os.replace(hidden, folder / part)
    return table.num_rows


def _trials(files: list[Described], out: Path, pa: Any, pq: Any) -> int:
    """``trials.parquet``: each trial between marks ``start`` and ``stop`` (their
    ``time``, on the clock of every record's ``time``: a query's ``time BETWEEN start
    AND stop``), a column per field its start mark carries (a field named as a column
    is left out)."""
    found = listed(("start", "stop"), _marks(files))
    columns: dict[str, list[Any]] = {
        "trial": [t.number for t in found],
        "start": [nanoseconds(t.start_mark.time) for t in found],
        "stop": [None if t.stop_mark is None else nanoseconds(t.stop_mark.time)
                 for t in found],
        "start_mark": [t.start_mark.text for t in found],
        "stop_mark": [None if t.stop_mark is None else t.stop_mark.text for t in found]}
    keys = dict.fromkeys(k for t in found for k, _ in t.start_mark.fields)
    for key in keys:
        if key not in columns:
            columns[key] = [dict(t.start_mark.fields).get(key) for t in found]
    types = {"trial": pa.int64(), "start": pa.timestamp("ns", tz="UTC"),
             "stop": pa.timestamp("ns", tz="UTC")}
    table = pa.table({name: pa.array(values, types.get(name, pa.string()))
                      for name, values in columns.items()})
    hidden = out / TEMPORARY.format(name=TRIALS)
    pq.write_table(table, hidden)
    os.replace(hidden, out / TRIALS)
    return len(found)
