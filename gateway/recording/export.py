"""Tables from recordings: one per node and record, a row per record.

Columns: ``time`` (with ``time_placed`` and ``time_bound_ms`` after it when the time is
refined after the fact: :mod:`.refined`), ``host_time``, ``device_time``, ``seq``,
``lost_before``, ``lqi``, ``rssi``, then the record's fields in the order of its
layout (:mod:`aspp.records`), vectors as ``<field>_x/_y/_z``, matrices as ``<field>_11``
.. ``<field>_33`` (row, column), a record's list of integers as ``<field>_1`` ..
``<field>_n``; then the fields the gateway adds (a matrix's ``roll``, ``pitch``,
``yaw``, and ``quaternion_w`` .. ``quaternion_z``: :data:`aspp.records.DERIVED_FROM_MATRIX`).
A value a record does not have (an untimed record's ``time``) or NaN (JSON's null) is an
empty cell or a null.

``lost_before`` is the samples of the node's stream missing just before the row, by its
timer's steps (:mod:`.losses`): 0 normally, for rows that are not a stream's (polled
records), and for a stream started afresh (counted from the node's start reply); empty
where it is not known: a record without a timer, a table's first row, the first row
after the node's timer restarted (a reboot) or the gateway's ``seq`` did.

Marks (``gx2ctl mark``) go in a table of their own, ``marks.csv``: ``time``,
``host_time``, ``nodes`` (their addresses, space-separated; empty: the whole
experiment), ``text``; written beside every export of tables, its header alone when
the window holds no mark (a script that reads it finds it).

Rows are written as they are read, once the WINDOW rows of their table after them are
read too (the steps that tell the stream's period): a CSV export holds that many rows a
table in memory, a Parquet one a batch of rows more (:mod:`.parquetfile`), a .mat one
the whole table (scipy's writer takes a struct whole: :mod:`.matfile`). The types the
formats give the columns: :mod:`.columns`. Each table is written under a temporary
name (TEMPORARY) and given its own when it is whole, so an export that fails or is
interrupted leaves no cut table where a whole one is expected, and replaces the table
of an earlier export only with a whole one.
"""

from __future__ import annotations

import contextlib
import csv
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import IO, Any

from aspp.records import BY_NAME, derived
from gateway.common.topics import parse

from .columns import Column, mark_columns, record_columns
from .files import MARK, STATUS, RecordingError
from .losses import Counted, Losses
from .matfile import MatWriter, mat_modules
from .parquetfile import MissingExtra, ParquetWriter, parquet_modules
from .reader import Entry, Mark, read_all
from .refined import COLUMNS as REFINED_COLUMNS
from .refined import Refinement
from .reports import Reading
from .rosbag import Bag, export_bag, ros2_modules
from .summary import Summary

LEADING = ("time", "host_time", "device_time", "seq", "lost_before", "lqi", "rssi")
REFINED_LEADING = (LEADING[0], *REFINED_COLUMNS, *LEADING[1:])
"""With ``time`` refined (:mod:`.refined`): how each row's time was placed, and its
bound, beside it."""
BOOKKEEPING = frozenset((*REFINED_LEADING, "node", "record", "command"))
FORMATS = ("csv", "parquet", "mat", "ros2")
"""Every format, each in a module of its own (:mod:`.parquetfile`, :mod:`.matfile`,
:mod:`.rosbag`) registered below: a table format in WRITERS, a format that writes a
window whole (a ROS 2 bag) in WHOLE."""
AXES = ("x", "y", "z")
MATRIX = tuple(f"{row}{column}" for row in (1, 2, 3) for column in (1, 2, 3))
MARKS = "marks"
TEMPORARY = ".{name}.partial"


def table_name(address: int, record: str, form: str) -> str:
    """The name of a node's table of ``record`` in format ``form``."""
    return f"{address}_{record}.{form}"


def earlier_tables(out: Path, form: str) -> list[Path]:
    """The tables of ``form`` an export writes that ``out`` holds already (an earlier
    export's): ``<address>_<record>.<form>`` of a record this version knows, and
    ``marks.<form>``; no other file (a user's ``2024_budget.csv`` is none of them)."""
    def is_table(name: str) -> bool:
        stem, dot, suffix = name.rpartition(".")
        if not dot or suffix != form:
            return False
        address, _, record = stem.partition("_")
        return stem == MARKS or (address.isascii() and address.isdigit()
                                 and record in BY_NAME)
    if not out.is_dir():
        return []
    return sorted(path for path in out.iterdir() if path.is_file() and is_table(path.name))


def field_columns(record: str, payload: Mapping[str, Any]) -> list[tuple[str, str, int]]:
    """(column, field, index) for each field column of ``record``: the layout's order
    for a known record, the payload's own order for one this version does not know
    (index -1: the value itself, not an element of it)."""
    spec = BY_NAME.get(record)
    if spec is not None:
        shapes = [(f.name, f.type.shape, f.type.items, f.elements)
                  for f in (*spec.reply, *derived(spec))]
    else:
        shapes = [(name, _shape(value), len(value) if isinstance(value, list) else 1, ())
                  for name, value in payload.items() if name not in BOOKKEEPING]
    columns: list[tuple[str, str, int]] = []
    for name, shape, items, elements in shapes:
        if name in BOOKKEEPING:
            continue
        if shape == "vector":
            columns += [(f"{name}_{axis}", name, i)
                        for i, axis in enumerate(elements or AXES)]
        elif shape == "matrix":
            columns += [(f"{name}_{cell}", name, i) for i, cell in enumerate(MATRIX)]
        elif shape == "ints":
            columns += [(f"{name}_{i + 1}", name, i) for i in range(items)]
        else:
            columns.append((name, name, -1))
    return columns


def _shape(value: Any) -> str:
    if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) for r in value):
        return "matrix"
    if isinstance(value, list):
        return "vector" if len(value) == 3 else "ints"
    return "scalar"


def element(value: Any, index: int) -> Any:
    """Element ``index`` of a vector, a matrix (row-major) or a list; None if absent."""
    if index < 0:
        return None if isinstance(value, (list, dict)) else value
    if isinstance(value, list) and value and isinstance(value[0], list):
        value = [item for row in value for item in row]
    if isinstance(value, list) and index < len(value):
        item = value[index]
        return None if isinstance(item, (list, dict)) else item
    return None


class Table:
    """One node's one record: its columns, fixed by its first row."""

    def __init__(self, node: int, record: str, first: Mapping[str, Any],
                 leading: tuple[str, ...] = LEADING) -> None:
        self.node, self.record = node, record
        self.leading = leading
        self.lost_at = leading.index("lost_before")
        self.fields = field_columns(record, first)
        self.columns = record_columns(record, leading, self.fields, first)
        """Its columns' names, kinds, meanings and units."""
        self.losses = Summary()
        """Its rows (``received``), what was missed while its base station was down,
        and what the file lost of them (the radio's and the gateway's losses are in
        ``lost_before``, not said)."""

    @property
    def rows(self) -> int:
        return self.losses.received

    def row(self, payload: Mapping[str, Any]) -> list[Any]:
        return [*(payload.get(name) for name in self.leading),
                *(element(payload.get(name), index) for _, name, index in self.fields)]


class Writer:
    """Where a format puts one table's rows."""

    def add(self, row: list[Any]) -> None: ...

    def close(self) -> None: ...


class CsvWriter(Writer):
    def __init__(self, path: Path, columns: list[Column]) -> None:
        self._file: IO[str] = path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow([column.name for column in columns])

    def add(self, row: list[Any]) -> None:
        # repr of a float reads back to the same float; None (null, NaN) is empty
        self._csv.writerow(["" if v is None else repr(v) if isinstance(v, float) else v
                            for v in row])

    def close(self) -> None:
        self._file.close()


WRITERS: dict[str, Callable[[Path, list[Column]], Writer]] = {
    "csv": CsvWriter, "parquet": ParquetWriter, "mat": MatWriter}
WHOLE: dict[str, Callable[..., Bag]] = {"ros2": export_bag}
"""The formats that write a window whole, not a table a node and record: each such
function takes :func:`export`'s arguments and the format's own, and says what it
wrote."""
EXTRAS: dict[str, Callable[[], object]] = {"parquet": parquet_modules, "mat": mat_modules,
                                           "ros2": ros2_modules}
"""What each format needs beyond the gateway's own dependencies: MissingExtra if absent."""


class Output:
    """One table's file: written under its temporary name, renamed when whole."""

    def __init__(self, out: Path, name: str, form: str, columns: list[Column],
                 outputs: list[Output]) -> None:
        self.path = out / name
        self.temporary = out / TEMPORARY.format(name=name)
        self.rows = 0
        self._writer: Writer | None = None
        # known to the export's clean-up before its file exists: a Ctrl-C that lands
        # just after the file is made (as a test's does, sent when a file appears) would
        # otherwise leave the temporary behind
        outputs.append(self)
        self._writer = WRITERS[form](self.temporary, columns)

    def add(self, row: list[Any]) -> None:
        self._writer.add(row)  # type: ignore[union-attr]
        self.rows += 1

    def finish(self) -> None:
        self._writer.close()  # type: ignore[union-attr]
        os.replace(self.temporary, self.path)

    def discard(self) -> None:
        # whatever went wrong (even a second Ctrl-C's in the first's clean-up), the
        # temporary goes: it is never taken for a table, being hidden and so named
        if self._writer is not None:
            with contextlib.suppress(Exception):
                self._writer.close()
        with contextlib.suppress(OSError):
            self.temporary.unlink()


def export(paths: Iterable[Path], out: Path, reading: Reading, form: str = "csv",
           progress: Callable[[Entry], None] | None = None,
           written: list[Path] | None = None, entries: Iterable[Entry] | None = None,
           tables_only: bool = False, refined: Refinement | None = None
           ) -> tuple[list[tuple[Path, Table]], int]:
    """Write the tables of the recordings ``paths`` into ``out``: (path, table) of each
    node's table, in the order first seen, and the number of marks (in ``marks.csv``).
    Each table written whole is added to ``written`` as it is. What reading skipped is
    in ``reading``. RecordingError for a message that is not a record's JSON object;
    MissingExtra for a format whose extra is not installed (Parquet: pyarrow, .mat:
    scipy); on any error, or Ctrl-C, no table that was not whole is left. ``entries``: the
    messages to export (a window of the recordings, :mod:`.window`) in place of every
    message of ``paths``. ``tables_only``: NoTables, and nothing written, if there is
    no table (only marks: the nodes asked are not in the recordings). ValueError, and
    nothing written, for a format that is not a table's (``ros2`` writes a window
    whole: WHOLE's function, :func:`.rosbag.export_bag`). ``refined``: each row's
    ``time`` refined after the fact (:mod:`.refined`), with its ``time_placed`` and
    ``time_bound_ms`` beside it."""
    if form in WHOLE:
        raise ValueError(f"export writes tables; format {form!r} writes a window whole: "
                         f"call {WHOLE[form].__module__}.{WHOLE[form].__name__}")
    if form not in WRITERS:
        raise ValueError(f"no export format {form!r}: one of {', '.join(FORMATS)}")
    if form in EXTRAS:
        EXTRAS[form]()
    out.mkdir(parents=True, exist_ok=True)
    tables: dict[tuple[int, str], tuple[Table, Output]] = {}
    losses: Losses[tuple[Table, Output, list[Any]]] = Losses()
    outputs: list[Output] = []
    marks: Output | None = None
    done = [] if written is None else written
    try:
        for entry in read_all(paths, reading) if entries is None else entries:
            if progress is not None:
                progress(entry)
            if entry.after_damage:
                losses.unread()
            if entry.topic == STATUS:
                # (only a hint for the losses: one that is not JSON is passed over, as
                # export passed every status over before; its tables lose nothing)
                with contextlib.suppress(RecordingError):
                    losses.status(entry.payload())
                continue
            if entry.topic == MARK:
                if marks is None:
                    marks = Output(out, f"{MARKS}.{form}", form, mark_columns(), outputs)
                marks.add(mark_row(Mark.of(entry)))
                continue
            where = parse(entry.topic)
            if where is None:
                continue
            payload = entry.payload()
            if refined is not None:
                payload = refined.apply(entry, payload)
            open_table = tables.get(where)
            if open_table is None:
                table = Table(*where, payload, LEADING if refined is None else REFINED_LEADING)
                output = Output(out, table_name(*where, form), form, table.columns,
                                outputs)
                open_table = tables[where] = (table, output)
            table, output = open_table
            _write(losses.add(*where, payload, (table, output, table.row(payload))), losses)
        _write(losses.finish(), losses)
        if tables_only and not tables:
            raise NoTables(out)
        if marks is None and tables:  # (its header alone: the window holds no mark)
            marks = Output(out, f"{MARKS}.{form}", form, mark_columns(), outputs)
        for output in outputs:
            output.finish()
            done.append(output.path)
    finally:
        for output in outputs:
            if output.path not in done:
                output.discard()
    return [(output.path, table) for table, output in tables.values()], (
        marks.rows if marks is not None else 0)


class NoTables(Exception):
    """An export that found marks but no table where tables were asked for."""


def _write(counted: list[Counted[tuple[Table, Output, list[Any]]]],
           losses: Losses[Any]) -> None:
    """Write rows whose ``lost_before`` is now known."""
    for row in counted:
        table, output, values = row.item
        values[table.lost_at] = row.lost
        output.add(values)
        table.losses.add(row, period=losses.period(table.node, table.record))


def mark_row(mark: Mark) -> list[Any]:
    return [mark.time, mark.host_time, " ".join(map(str, mark.nodes)), mark.text]


__all__ = ["FORMATS", "MissingExtra", "NoTables", "RecordingError", "export",
           "field_columns"]
