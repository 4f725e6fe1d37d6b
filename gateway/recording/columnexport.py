"""Export a batch of rows at a time (:mod:`.columnar`), every table format (CSV and .mat
as :mod:`.cells` makes their cells): the same tables, rows, ``lost_before``, marks and
losses as :func:`.export.export` writes row by row, from the same messages (windows,
duplicates and damage as :mod:`.reader` and :mod:`.window` give them, a chunk at a
time: a :class:`.blocks.Block`), at a fraction of the cost (bench/exportformats.py).

A table's messages wait, as their JSON, until BATCH of them are in; then they become
columns at once and are counted (:mod:`.batchsteps`): a table holds at most a batch
and the WINDOW rows whose ``lost_before`` is not yet known. A continuous-mode reply or
a damaged stretch is given to the streams where the row by row export gives it: the
batches waiting before it are counted first.
"""

from __future__ import annotations

import contextlib
import csv
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from gateway.common.topics import parse

from .batchsteps import NONE, Decided, add_many, flush
from .blocks import Block
from .columnar import Columns
from .columns import Column, mark_columns
from .entry import Entry
from .files import MARK, STATUS, RecordingError
from .losses import STARTED, Losses, Stream
from .marks import Mark
from .matfile import MatWriter
from .parquetfile import BATCH, parquet_modules
from .reader import read_all_blocks
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


class CsvTables:
    """A table's CSV file, a batch of rows (texts: :mod:`.cells`) at a time: each row's
    cells joined by Arrow, the batch written as one text; what ``csv.writer`` writes,
    which writes a batch whose texts need quoting (a comma, a quote, a line break)."""

    def __init__(self, path: Path, schema: Any) -> None:
        import pyarrow.compute
        self._pa, self._pc = parquet_modules()[0], pyarrow.compute
        self._file = path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(schema.names)

    def add(self, table: Any) -> None:
        pa, pc = self._pa, self._pc
        texts = [column if column.type == pa.string() else pc.cast(column, pa.string())
                 for column in table.columns]
        lines = pc.binary_join_element_wise(*texts, ",", null_handling="replace",
                                            null_replacement="")
        text = "\r\n".join(lines.to_pylist()) + "\r\n" if len(lines) else ""
        # (as many commas as cells apart, a line break a row, no quote: nothing to quote)
        rows = len(lines)
        if (text.count(",") == rows * (len(texts) - 1) and text.count("\n") == rows
                and text.count("\r") == rows and '"' not in text):
            self._file.write(text)
        else:
            self._csv.writerows(zip(*(column.to_pylist() for column in texts), strict=True))

    def close(self) -> None:
        self._file.close()


class MatTables:
    """A table's .mat file, a batch of rows (doubles and texts: :mod:`.cells`) at a time
    into :class:`.matfile.MatWriter`, which writes the struct whole when closed."""

    def __init__(self, path: Path, schema: Any) -> None:
        pa, _ = parquet_modules()
        self._texts = [field.type == pa.string() for field in schema]
        self._writer = MatWriter(path, [Column(
            field.name, "text" if text else "float",
            (field.metadata or {}).get(b"description", b"").decode(),
            (field.metadata or {}).get(b"unit", b"").decode())
            for field, text in zip(schema, self._texts, strict=True)])

    def add(self, table: Any) -> None:
        self._writer.add_columns([
            column.to_pylist() if text else
            column.to_numpy().astype(np.float64)  # (a null: NaN)
            for column, text in zip(table.columns, self._texts, strict=True)])

    def close(self) -> None:
        self._writer.close()


BATCH_WRITERS: dict[str, Callable[[Path, Any], Any]] = {
    "parquet": ParquetTables, "csv": CsvTables, "mat": MatTables}
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
                   progress: Callable[[int], None] | None = None,
                   written: list[Path] | None = None, blocks: Iterable[Block] | None = None,
                   tables_only: bool = False) -> tuple[list[tuple[Path, Table]], int]:
    """:func:`.export.export`, a batch at a time: its arguments, its result."""
    pa, _ = parquet_modules()
    # pyarrow imports pandas (where installed) at its first conversion of a value: done
    # here, before any table is made, as a Ctrl-C that lands in that import can be lost
    # there (the export went on to exit 0 in 3 of 16 runs interrupted in its first
    # second, bench-like; tests/recording/test_damage.py's Ctrl-C test now and then)
    pa.array([0])
    out.mkdir(parents=True, exist_ok=True)
    outputs: list[Output] = []
    done = [] if written is None else written
    with kept(outputs, done):  # (finished whole, or discarded)
        tables = _Tables(out, form, pa, outputs)
        for block in read_all_blocks(paths, reading) if blocks is None else blocks:
            if progress is not None:
                progress(block.bytes)
            tables.take(block)
        tables.finish()
        if tables_only and not tables.open:
            raise NoTables(out)
        if tables.marks is None and tables.open:
            tables.marks = Output(out, f"{MARKS}.{form}", form, mark_columns(), outputs)
    return [(t.output.path, t.table) for t in tables.open.values()], (
        tables.marks.rows if tables.marks is not None else 0)


_SKIP, _STATUS, _MARK = 0, 1, 2
"""What a block's message is to the export, by its channel: passed over, a status, a
mark; from 3 on, a table's message (its number in ``_Tables.order`` plus 3)."""


class _Tables:
    """An export's tables, their messages taken a block at a time: each table's picked
    out of a block by numpy and decoded a batch at a time, a status, a mark or a
    continuous-mode reply handled in its place among them."""

    def __init__(self, out: Path, form: str, pa: Any, outputs: list[Output]) -> None:
        self.out, self.form, self.pa, self.outputs = out, form, pa, outputs
        self.losses: Losses[int] = Losses()
        self.open: dict[tuple[int, str], _Open] = {}
        """The tables opened, in the order first met."""
        self.order: list[tuple[int, str]] = []
        """Each table's (node, record) by its kind (less 3), numbered when first in a
        block (it is opened at its first message)."""
        self._kinds: dict[tuple[int, str], int] = {}
        self.marks: Output | None = None
        self._places: dict[str, tuple[int, str] | None] = {}
        """Each topic's (node, record), parsed once."""

    def take(self, block: Block) -> None:
        """The block's messages, in order."""
        if not len(block):
            return
        if block.after_damage:
            for open_table in self.open.values():
                _count(open_table, self.pa)
            self.losses.unread()
        kinds = self._kinds_of(block)
        # where a status, a mark or a continuous-mode reply is, the messages before it
        # (up to it, for a reply: it is its table's row) are taken first
        events = np.flatnonzero(np.isin(kinds, self._events()))
        start = 0
        for at in events.tolist():
            self._segment(block, kinds, start, at + 1)
            self._event(block, int(kinds[at]), at)
            start = at + 1
        self._segment(block, kinds, start, len(block))

    def _kinds_of(self, block: Block) -> np.ndarray:
        """What each message of the block is (_SKIP, _STATUS, _MARK or a table)."""
        lookup = np.zeros(max(block.topics) + 1, np.int64)
        for channel, topic in block.topics.items():
            lookup[channel] = self._kind(topic)
        return lookup[np.frombuffer(block.channel, np.uint16)]

    def _kind(self, topic: str) -> int:
        if topic == STATUS:
            return _STATUS
        if topic == MARK:
            return _MARK
        where = self._places[topic] if topic in self._places else self._places.setdefault(
            topic, parse(topic))
        if where is None:
            return _SKIP
        kind = self._kinds.get(where)
        if kind is None:
            kind = self._kinds[where] = len(self.order) + 3
            self.order.append(where)
        return kind

    def _events(self) -> list[int]:
        """The kinds of message handled in their place (a status, a mark, a reply)."""
        return [_STATUS, _MARK, *(kind for where, kind in self._kinds.items()
                                  if where[1] == STARTED)]

    def _segment(self, block: Block, kinds: np.ndarray, start: int, stop: int) -> None:
        """The block's table messages from ``start`` to ``stop``, each added to its
        table with its node's count of messages so far; a table with a batch in
        counted."""
        if start >= stop:
            return
        kinds = kinds[start:stop]
        present, first = np.unique(kinds, return_index=True)
        tables = present[np.argsort(first)]  # (in the order first met: opened so)
        tables = tables[tables > _MARK].tolist()
        nodes: dict[int, np.ndarray] = {}
        data = block.data
        for kind in tables:
            where = self.order[kind - 3]
            node = where[0]
            if node not in nodes:  # (every record of the node counts, in order)
                mine = np.zeros(len(kinds), np.int64)
                for other in tables:
                    if self.order[other - 3][0] == node:
                        mine += kinds == other
                running = self.losses._counts.get(node, 0) + np.cumsum(mine)
                self.losses._counts[node] = int(running[-1])
                nodes[node] = running
            at = np.flatnonzero(kinds == kind)
            open_table = self.open.get(where)
            if open_table is None:  # (its first message: its columns)
                first = Entry(block.topics[block.channel[start + int(at[0])]], 0, 0,
                              data[start + int(at[0])])
                open_table = self.open[where] = _opened(first, where, self.out, self.form,
                                                        self.losses, self.outputs)
            if len(at) == stop - start:
                open_table.messages.extend(data[start:stop])
            else:
                open_table.messages.extend([data[start + i] for i in at.tolist()])
            open_table.counts.extend(nodes[node][at].tolist())
            if len(open_table.messages) >= BATCH:
                _count(open_table, self.pa)

    def _event(self, block: Block, kind: int, at: int) -> None:
        """A status, a mark, or a continuous-mode reply (its row already taken)."""
        entry = Entry(block.topics[block.channel[at]], block.log_time[at],
                      block.publish_time[at], block.data[at])
        if kind == _STATUS:
            with contextlib.suppress(RecordingError):
                self.losses.status(entry.payload())
        elif kind == _MARK:
            if self.marks is None:
                self.marks = Output(self.out, f"{MARKS}.{self.form}", self.form,
                                    mark_columns(), self.outputs)
            self.marks.add(mark_row(Mark.of(entry)))
        else:
            node = self.order[kind - 3][0]
            payload = entry.payload()
            for (owner, _), other in self.open.items():
                if owner == node:
                    _count(other, self.pa)
            count = self.losses._counts[node]
            self.losses._started[node] = (payload, count)
            for (owner, _), stream in self.losses.streams.items():
                if owner == node:
                    stream.started(payload, count)

    def finish(self) -> None:
        for open_table in self.open.values():
            _count(open_table, self.pa)
            flush(open_table.stream, open_table.decided)
            _write(open_table, self.pa)


def _opened(entry: Entry, where: tuple[int, str], out: Path, form: str,
            losses: Losses[int], outputs: list[Output]) -> _Open:
    """A table's first message: its columns, its stream (begun where a continuous-mode
    reply of its node began it, as :meth:`.losses.Losses.add` begins it)."""
    node, record = where
    table = Table(node, record, entry.payload())
    columns = Columns(entry.topic, table.columns, table.fields, LEADING, form)
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
