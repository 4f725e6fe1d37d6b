"""Recordings as a Parquet dataset (``gx2ctl dataset RECORDINGS OUT``), partitioned
Hive-style as DuckDB, Polars, Spark, Trino and Athena read it as it is:
``OUT/record=<record>/node=<address>/date=<YYYY-MM-DD>/part-<file>.parquet``, the
columns and types of ``export --format parquet`` (:mod:`.columnexport`), a part per
recording, node, record and UTC day of its rows' ``time``; and ``OUT/trials.parquet``,
the trials the marks define (:mod:`.trials`), each run's merged into the earlier ones
(a trial whose recording retention deleted keeps its row and number: see _trials).

Incremental and idempotent: ``OUT/_converted.json`` names the RECORDINGS directory
(an OUT takes one: parts are named by file name) and each recording converted (its size
and modification time); a run converts only the finished recordings not in it, or
changed since (their old parts replaced), so a timer running it keeps the dataset
minutes behind the recorder. One run at a time (an exclusive flock on ``OUT/.lock``: a
second says so and does nothing), which first removes what a killed run left. A
recording that cannot be read is said and left for the next run, the rest converted; a
copy of one converted (the catalogue's same_as) is skipped. Every part is written in
the hidden work folder, a batch at a time, and renamed into its partition when whole: a
partition's folder holds nothing but whole parts, even after a run killed half way (a
Polars scan of a folder reads every file in it, hidden or not;
tests/recording/test_dataset_killed.py). The list of what was converted is replaced
after each recording. A recording gone (retention, a move)
leaves its parts: the dataset is never trimmed by what the recorder deletes.

``--time refined`` (:mod:`.refined`) makes a dataset of refined times: each recording's
rows placed after the fact from it and the recordings around it (4 minutes either
side), with ``time_placed`` and ``time_bound_ms`` after ``time``, written row by row as
export writes a refined table. A dataset holds one kind of time (``_converted.json``'s
``time``): a run asking the other is refused. A recording converted before the one
after it was finished is placed from the recordings before it, and its last minutes
from one side of the stretch, as live; it is not converted again when the next one
comes (the parts of a recording are made once).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .catalogue import Described, catalogue
from .columnexport import export_batches
from .export import export
from .files import RecordingError
from .parquetfile import BATCH, converted, parquet_modules
from .reports import Reading
from .tables import TEMPORARY
from .trials import listed
from .window import Window, _marks

CONVERTED = "_converted.json"
BUSY = 75
"""gx2ctl dataset's exit status when another run holds OUT's lock (EX_TEMPFAIL: try again
later; the timer's next run does)."""
TRIALS = "trials.parquet"
WORK = ".converting"
"""Where a recording's tables are exported before they are parted (hidden: no query's
glob takes it)."""
LOCK = ".lock"
"""Held (flock, exclusive) by the run converting into OUT: one run at a time."""


class Busy(Exception):
    """Another run is converting into OUT (it holds OUT/.lock): this one did nothing."""


class OtherRecordings(Exception):
    """OUT holds the recordings of another directory (_converted.json's
    ``recordings``): a part is named by its recording's file name alone, so two
    directories' same-named recordings would replace each other's parts. Or it holds
    the other kind of time (``time``: a dataset's rows are all live or all refined)."""


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
    failed: list[str] = field(default_factory=list)
    """A line for each recording that could not be converted (naming it): left
    unstamped, tried again by the next run; the run is partial."""
    gone: list[Path] = field(default_factory=list)
    """Recordings deleted (retention, a move) while the run ran: skipped."""
    same: list[tuple[Path, str]] = field(default_factory=list)
    """Recordings the same as one converted (a copy: the catalogue's same_as), and the
    name of that one: skipped (stamped, with it named)."""
    warnings: list[str] = field(default_factory=list)
    """A line for each recording converted that overlaps one converted before it (the
    rows recorded in both are in the dataset twice)."""


def convert(paths: list[Path], out: Path, reading: Reading,
            said: Callable[[str], None] = lambda line: None,
            recordings: Path | None = None, time: str = "live") -> Converted:
    """Convert the recordings ``paths`` (of the directory ``recordings``: by default
    the first's) not yet converted into the dataset ``out``, their ``time`` live or
    refined; OtherRecordings if ``out`` holds another directory's, or the other time."""
    pa, pq = parquet_modules()
    out.mkdir(parents=True, exist_ok=True)
    with _locked(out):
        _cleared(out)
        return _converted(paths, out, reading, said, pa, pq, _folder(recordings, paths),
                          time)


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """OUT/.lock held for the run (released when the run ends, or dies: the kernel's
    flock); Busy if another run holds it (the timer's, and one by hand)."""
    descriptor = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise Busy(f"{out}: another gx2ctl dataset is converting into it (it holds "
                       f"{out / LOCK}); this run did nothing") from None
        yield
    finally:
        os.close(descriptor)


def _cleared(out: Path) -> None:
    """What a run killed (SIGTERM, SIGKILL, a power cut) left half made: the work
    folder, and the hidden partial files of OUT and of its partitions (an earlier
    version's). Only under the lock: no other run is making them."""
    shutil.rmtree(out / WORK, ignore_errors=True)
    for stale in [*out.glob(".*.partial"), *out.glob("record=*/node=*/date=*/.*.partial")]:
        with contextlib.suppress(FileNotFoundError):
            stale.unlink()


def _folder(recordings: Path | None, paths: list[Path]) -> str:
    """The directory of the recordings, resolved (a file given: its directory)."""
    given = recordings if recordings is not None else paths[0]
    return str(given.resolve() if given.is_dir() else given.resolve().parent)


def _converted(paths: list[Path], out: Path, reading: Reading,
               said: Callable[[str], None], pa: Any, pq: Any, folder: str,
               time: str) -> Converted:
    state = _load(out / CONVERTED)
    kept = state.setdefault("recordings", folder)
    if kept != folder:
        raise OtherRecordings(
            f"{out} holds the recordings of {kept} ({out / CONVERTED}), and {folder} is "
            "another directory: its same-named recordings would replace those parts; "
            "give it an OUT of its own")
    # (a dataset made before --time holds live times)
    made = state.setdefault("time", time if not state["files"] else "live")
    if made != time:
        raise OtherRecordings(
            f"{out} is a dataset of {made} times ({out / CONVERTED}): --time {time} "
            "needs an OUT of its own (a dataset's rows are all of one time)")
    done: dict[str, Any] = state["files"]
    files = catalogue(paths, read_writing=False)
    result = Converted([], 0, [], 0)
    for described in files:
        key = described.path.name
        if described.writing:
            result.writing.append(described.path)
            continue
        try:
            stamp = _stamp(described.path)
            if _unchanged(done.get(key), stamp):
                result.current += 1
                continue
            twin = next((p.name for p in described.same_as
                         if p.name != key and _holds(done, p.name)), None)
            if twin is not None:
                done[key] = {**stamp, "same_as": twin}
                _save(out / CONVERTED, state)
                result.same.append((described.path, twin))
                said(f"{described.path}  the same as {twin} (converted): skipped")
                continue
            rows = _convert_one(described, out, reading, pq,
                                files if time == "refined" else None)
        except (RecordingError, OSError) as error:
            if not described.path.exists():  # (retention deleted it while we ran)
                result.gone.append(described.path)
                said(f"{described.path}  gone (deleted while converted), skipped")
                continue
            if isinstance(error, OSError) and not _names(error, described.path):
                raise  # (OUT's trouble, not the recording's: the run cannot go on)
            why = str(error) if isinstance(error, RecordingError) else \
                (error.strerror or str(error))
            result.failed.append(why if str(described.path) in why
                                 else f"{described.path}: {why}")
            continue
        overlapped = [p.name for p in described.overlaps
                      if p.name != key and _holds(done, p.name)]
        if overlapped:
            result.warnings.append(
                f"{described.path} overlaps {', '.join(overlapped)} (converted): the rows "
                "recorded in both are in the dataset twice")
        done[key] = stamp
        _save(out / CONVERTED, state)
        result.files.append((described.path, rows))
        said(f"{described.path}  {rows:,} rows")
    result.trials = _trials(files, out, pa, pq)
    return result


def _names(error: OSError, path: Path) -> bool:
    """Whether ``error`` is about the recording ``path`` (not about OUT)."""
    return any(name is not None and os.fspath(name) == os.fspath(path)
               for name in (error.filename, error.filename2))


def _unchanged(kept: Any, stamp: dict[str, int]) -> bool:
    return isinstance(kept, dict) and all(kept.get(k) == v for k, v in stamp.items())


def _holds(done: dict[str, Any], name: str) -> bool:
    """Whether the recording ``name`` has its own parts (converted, not skipped as the
    same as another)."""
    kept = done.get(name)
    return isinstance(kept, dict) and "same_as" not in kept


def _stamp(path: Path) -> dict[str, int]:
    status = path.stat()
    return {"bytes": status.st_size, "mtime_ns": status.st_mtime_ns}


def _load(path: Path) -> dict[str, Any]:
    """``{"recordings": DIR, "files": {NAME: STAMP}}``; an earlier version's
    ``{NAME: STAMP}`` read as the files (its directory the one given now)."""
    try:
        loaded = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {"files": {}}
    if not isinstance(loaded, dict):
        return {"files": {}}
    if isinstance(loaded.get("files"), dict) and isinstance(loaded.get("recordings"), str):
        return loaded
    return {"files": loaded}


def _save(path: Path, done: dict[str, Any]) -> None:
    hidden = path.with_name(TEMPORARY.format(name=path.name))
    hidden.write_text(json.dumps(done, indent=1, sort_keys=True), encoding="utf-8")
    os.replace(hidden, path)


def _convert_one(described: Described, out: Path, reading: Reading, pq: Any,
                 around: list[Described] | None = None) -> int:
    """One recording's tables exported (its times refined from the recordings
    ``around`` it, if given), then parted by day: its rows."""
    work = out / WORK / described.path.stem
    shutil.rmtree(work, ignore_errors=True)
    try:
        if around is None or not described.nodes:  # (no record: nothing to refine)
            tables, _ = export_batches([described.path], work, reading, "parquet")
        else:
            from .refined import check_refinable, for_window
            check_refinable([described])
            span = None if described.start is None else (described.start,
                                                          (described.end or 0) + 1)
            tables, _ = export([described.path], work, reading, "parquet",
                               refined=for_window(around, Window(span)))
        part = f"part-{described.path.stem}.parquet"
        for folder in out.glob("record=*/node=*/date=*/"):
            # (a recording changed since: its parts made again; the name matched
            # exactly, never as a pattern: a file named s[12].mcap is not s1.mcap)
            with contextlib.suppress(FileNotFoundError):
                (folder / part).unlink()
        rows = 0
        for path, table in tables:
            rows += _parted(path, out, work, table.record, table.node, part, pq)
        return rows
    finally:
        shutil.rmtree(work, ignore_errors=True)
        with contextlib.suppress(OSError):
            (out / WORK).rmdir()


def _parted(source: Path, out: Path, work: Path, record: str, node: int, part: str,
            pq: Any) -> int:
    """A table's rows (the exported file ``source``, read a batch at a time: memory
    flat however long the recording) written to the day partitions of their time (else
    host_time), each day's part made in ``work`` (on the dataset's file system), a
    batch at a time, and renamed there when whole."""
    import pyarrow.compute as pc
    exported = pq.ParquetFile(source)
    writers: dict[str | None, tuple[Any, Path]] = {}
    rows = 0
    try:
        for batch in exported.iter_batches(batch_size=BATCH):  # (export's batch)
            when = pc.coalesce(batch.column("time"), batch.column("host_time"))
            days = pc.strftime(when, format="%Y-%m-%d")
            for day in pc.unique(days).to_pylist():
                if day not in writers:
                    hidden = work / TEMPORARY.format(name=f"{record}.{node}.{day}.{part}")
                    writers[day] = (pq.ParquetWriter(hidden, exported.schema_arrow), hidden)
                writers[day][0].write_batch(
                    batch.filter(pc.is_null(days) if day is None else pc.equal(days, day)))
            rows += batch.num_rows
    finally:
        for writer, _ in writers.values():
            writer.close()
    for day, (_, hidden) in writers.items():
        folder = out / f"record={record}" / f"node={node}" / f"date={day or 'unknown'}"
        folder.mkdir(parents=True, exist_ok=True)
        os.replace(hidden, folder / part)
    return rows


def _trials(files: list[Described], out: Path, pa: Any, pq: Any) -> int:
    """``trials.parquet``: each trial between marks ``start`` and ``stop`` (their
    ``time``, on the clock of every record's ``time``: a query's ``time BETWEEN start
    AND stop``), a column per field its start mark carries (a field named as a column
    is left out).

    Merged with the trials.parquet of earlier runs, never dropping one: a trial is
    known by its start mark (its ``time`` and text); one in the recordings now replaces
    its row (an open trial gets its stop), one whose recording retention deleted keeps
    its row. A trial keeps the number it was first given; a new one is numbered on from
    the highest (so numbers follow the marks' order as recordings arrive in order)."""
    found = listed(("start", "stop"), _marks(files))
    # (as export converts a time: one beyond timestamp[ns], a foreign mark's, null)
    starts = converted("time", tuple(t.start_mark.time for t in found))
    stops = converted("time", tuple(None if t.stop_mark is None else t.stop_mark.time
                                    for t in found))
    rows = {(row["start"], row["start_mark"]): row for row in _earlier(out / TRIALS, pa, pq)}
    number = max((row["trial"] for row in rows.values()), default=0)
    for trial, start, stop in zip(found, starts, stops, strict=True):
        key = (start, trial.start_mark.text)
        kept = rows.get(key)
        if kept is None:
            number += 1
        row = {"trial": number if kept is None else kept["trial"], "start": start,
               "stop": stop, "start_mark": trial.start_mark.text,
               "stop_mark": None if trial.stop_mark is None else trial.stop_mark.text}
        for name, value in trial.start_mark.fields:
            row.setdefault(name, value)
        rows[key] = row
    ordered = sorted(rows.values(), key=lambda row: row["trial"])
    names = dict.fromkeys(name for row in ordered for name in row)
    types = {"trial": pa.int64(), "start": pa.timestamp("ns", tz="UTC"),
             "stop": pa.timestamp("ns", tz="UTC")}
    table = pa.table({name: pa.array([row.get(name) for row in ordered],
                                     types.get(name, pa.string())) for name in names})
    hidden = out / TEMPORARY.format(name=TRIALS)
    pq.write_table(table, hidden)
    os.replace(hidden, out / TRIALS)
    return len(ordered)


def _earlier(path: Path, pa: Any, pq: Any) -> list[dict[str, Any]]:
    """The rows of an earlier run's trials.parquet, times as ns; none if there is none
    (or it cannot be read: made again from the recordings present)."""
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException):
        return []
    for name in ("start", "stop"):
        if name in table.column_names:
            table = table.set_column(table.column_names.index(name), name,
                                     table.column(name).cast(pa.int64()))
    return [row for row in table.to_pylist() if isinstance(row.get("trial"), int)]
