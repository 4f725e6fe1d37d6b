"""Export a batch of rows at a time (:mod:`.columnar`), for the formats that take Arrow
tables whole (Parquet): the same tables, rows, ``lost_before``, marks and losses as
:func:`.export.export` writes row by row, from the same messages (windows, duplicates
and damage as :mod:`.reader` and :mod:`.window` give them), at a fraction of the cost
(bench/exportformats.py).

A table's messages wait, as their JSON, until BATCH of them are in; then they become
columns at once and are counted (:mod:`.batchsteps`): a table holds at most a batch
and the WINDOW rows whose ``lost_before`` is not yet known. A continuous-mode reply or
a damaged stretch is given to the streams where the row by row export gives it: the
batches waiting before it are counted first.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from gateway.common.topics import parse

from .batchsteps import NONE, Decided, add_many, flush
from .columnar import Columns
from .columns import Column, mark_columns
from .files import MARK, STATUS, RecordingError
from .losses import STARTED, Losses, Stream
from .marks import Mark
from .parquetfile import BATCH, parquet_modules
from .reader import Entry, read_all
from .reports import Reading
from .tables import LEADING, MARKS, NoTables, Output, Table, kept, mark_row, table_name


class ParquetTables:
    """A table's Parquet file, written a row group of BATCH rows at a time."""

    def __init__(self, path: Path, schema: Any) -> None:
        self._pa, pq = parquet_modules()
        self._writer = pq.ParquetWriter(path, schema)
        self._waiting: list[Any] = []
        self._rows = 0

    def add(self, table: Any) -> None:
        self._waiting.append(table)
        self._rows += table.num_rows
        if self._rows >= BATCH:
            self._flush()

    def _flush(self) -> None:
        if self._rows:
            self._writer.write_table(self._pa.concat_tables(self._waiting))
        self._waiting, self._rows = [], 0

    def close(self) -> None:
        self._flush()
        self._writer.close()


BATCH_WRITERS: dict[str, Callable[[Path, Any], Any]] = {"parquet": ParquetTables}
"""The formats exported a batch at a time: how each writes a table's batches."""


class _Open:
    """A table being exported: its messages waiting, its rows not yet decided."""

    def __init__(self, table: Table, columns: Columns, stream: Stream[int],
                 output: Output) -> None:
        self.table, self.columns, self.stream, self.output = table, columns, stream, output
        self.messages: list[bytes] = []
        self.counts: list[int] = []
        self.added = 0
        """Rows added to the stream so far (the next one's number)."""
        self.held: Any = None
        """The rows added and not yet written (a pyarrow Table), from ``base``."""
        self.base = 0
        self.decided = Decided()


def export_batches(paths: Iterable[Path], out: Path, reading: Reading, form: str,
                   progress: Callable[[Entry], None] | None = None,
                   written: list[Path] | None = None, entries: Iterable[Entry] | None = None,
                   tables_only: bool = False) -> tuple[list[tuple[Path, Table]], int]:
    """:func:`.export.export`, a batch at a time: its arguments, its result."""
    pa, _ = parquet_modules()
    out.mkdir(parents=True, exist_ok=True)
    losses: Losses[int] = Losses()
    tables: dict[tuple[int, str], _Open] = {}
    outputs: list[Output] = []
    marks: Output | None = None
    done = [] if written is None else written
    places: dict[str, tuple[int, str] | None] = {}
    """Each topic's (node, record), parsed once."""
    with kept(outputs, done):  # (finished whole, or discarded)
        for entry in read_all(paths, reading) if entries is None else entries:
            if progress is not None:
                progress(entry)
            topic = entry.topic
            if entry.after_damage:
                for open_table in tables.values():
                    _count(open_table, pa)
                losses.unread()
            if topic == STATUS:
                with contextlib.suppress(RecordingError):
                    losses.status(entry.payload())
                continue
            if topic == MARK:
                if marks is None:
                    marks = Output(out, f"{MARKS}.{form}", form, mark_columns(), outputs)
                marks.add(mark_row(Mark.of(entry)))
                continue
            where = places[topic] if topic in places else places.setdefault(
                topic, parse(topic))
            if where is None:
                continue
            node = where[0]
            count = losses._counts[node] = losses._counts.get(node, 0) + 1
            open_table = tables.get(where)
            if open_table is None:
                open_table = tables[where] = _opened(entry, where, out, form, losses,
                                                     outputs)
            open_table.messages.append(entry.data)
            open_table.counts.append(count)
            if where[1] == STARTED:
                payload = entry.payload()
                for (owner, _), other in tables.items():
                    if owner == node:
                        _count(other, pa)
                losses._started[node] = (payload, count)
                for (owner, _), stream in losses.streams.items():
                    if owner == node:
                        stream.started(payload, count)
            elif len(open_table.messages) >= BATCH:
                _count(open_table, pa)
        for open_table in tables.values():
            _count(open_table, pa)
            flush(open_table.stream, open_table.decided)
            _write(open_table, pa)
        if tables_only and not tables:
            raise NoTables(out)
        if marks is None and tables:
            marks = Output(out, f"{MARKS}.{form}", form, mark_columns(), outputs)
    return [(t.output.path, t.table) for t in tables.values()], (
        marks.rows if marks is not None else 0)


def _opened(entry: Entry, where: tuple[int, str], out: Path, form: str,
            losses: Losses[int], outputs: list[Output]) -> _Open:
    """A table's first message: its columns, its stream (begun where a continuous-mode
    reply of its node began it, as :meth:`.losses.Losses.add` begins it)."""
    node, record = where
    table = Table(node, record, entry.payload())
    columns = Columns(entry.topic, table.columns, table.fields, LEADING)
    stream = losses.streams[where] = Stream(
        losses.ahead, lambda after, at: losses.outages.back(node, after, at))
    if node in losses._started:
        stream.started(*losses._started[node])
    output = Output(out, table_name(node, record, form), form, table.columns, outputs,
                    lambda path: BATCH_WRITERS[form](path, columns.schema))
    return _Open(table, columns, stream, output)


def _count(open_table: _Open, pa: Any) -> None:
    """The table's waiting messages made columns and counted; the rows decided written."""
    if not open_table.messages:
        return
    batch = open_table.columns.batch(open_table.messages, open_table.counts)
    open_table.messages, open_table.counts = [], []
    held = open_table.held
    open_table.held = batch.table if held is None else pa.concat_tables([held, batch.table])
    add_many(open_table.stream, batch.rows, open_table.decided, open_table.added)
    open_table.added += batch.table.num_rows
    _write(open_table, pa)


def _write(open_table: _Open, pa: Any) -> None:
    """Write the rows decided, in the order decided, with their ``lost_before``."""
    items, lost, gateway, unread, down = open_table.decided.arrays()
    if not len(items):
        return
    held, base = open_table.held, open_table.base
    rows = held.take(pa.array(items - base)) if not _in_order(items, base) else \
        held.slice(0, len(items))
    at = LEADING.index("lost_before")
    rows = rows.set_column(at, rows.schema.field(at),
                           pa.array(lost, pa.int64(), mask=lost == NONE))
    open_table.output._writer.add(rows)  # type: ignore[union-attr]
    open_table.output.rows += rows.num_rows
    pending = [row.item for row in open_table.stream._pending]
    keep = min(pending, default=open_table.added)
    open_table.held = held.slice(keep - base)
    open_table.base = keep
    summary = open_table.table.losses
    known = np.where(lost == NONE, 0, lost)
    summary.received += len(items)
    summary.radio += int(np.maximum(0, known - gateway - unread - down).sum())
    summary.gateway += int(gateway.sum())
    summary.down += int(down.sum())
    summary.unread += int(unread.sum())
    summary.unread_seconds += int(unread.sum()) * (open_table.stream.seconds or 0.0)


def _in_order(items: np.ndarray, base: int) -> bool:
    return bool(items[0] == base and items[-1] == base + len(items) - 1
                and (len(items) < 2 or np.all(np.diff(items) == 1)))


__all__ = ["BATCH_WRITERS", "Column", "export_batches"]
