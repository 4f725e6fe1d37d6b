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
read too (the steps that tell the stream's period): an export a batch at a time
(:mod:`.columnexport`: every format, where pyarrow is installed, but a refined time)
holds that many rows a table in memory and a batch of them, row by row (CSV without
pyarrow) the WINDOW rows alone, a .mat one the whole table (scipy's writer takes a
struct whole: :mod:`.matfile`). The types the formats give the columns:
:mod:`.columns`. Each table is written under a temporary
name (TEMPORARY) and given its own when it is whole, so an export that fails or is
interrupted leaves no cut table where a whole one is expected, and replaces the table
of an earlier export only with a whole one.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from aspp.records import BY_NAME
from gateway.common.topics import parse

from .blocks import Block, entries_of
from .columns import mark_columns
from .files import MARK, STATUS, RecordingError
from .losses import Counted, Losses
from .marks import Mark
from .matfile import mat_modules
from .parquetfile import MissingExtra, parquet_modules
from .reader import read_all
from .refined import Refinement
from .reports import Reading
from .rosbag import Bag, export_bag, ros2_modules
from .tables import MARKS, WRITERS, NoTables, Output, Table, kept, mark_row, table_name

FORMATS = ("csv", "parquet", "mat", "ros2")
"""Every format, each in a module of its own (:mod:`.parquetfile`, :mod:`.matfile`,
:mod:`.rosbag`) registered: a table format in :data:`.tables.WRITERS`, a format that
writes a window whole (a ROS 2 bag) in WHOLE below."""


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


WHOLE: dict[str, Callable[..., Bag]] = {"ros2": export_bag}
"""The formats that write a window whole, not a table a node and record: each such
function takes :func:`export`'s arguments and the format's own, and says what it
wrote."""
EXTRAS: dict[str, Callable[[], object]] = {"parquet": parquet_modules, "mat": mat_modules,
                                           "ros2": ros2_modules}
"""What each format needs beyond the gateway's own dependencies: MissingExtra if absent."""
SMALL = 1 << 20
"""Bytes of recordings under which CSV and .mat go row by row. A batch at a time is 4x
faster a row (22 against 5.3 us), but it decodes with pyarrow, whose import (and
pandas' through it) costs 0.3 s of CPU first: past about 18,000 rows, a megabyte of
recording or so, it has paid for itself. (A 20 s recording to CSV: 0.25 s of CPU row
by row, 0.55 s a batch at a time.)"""


def export(paths: Iterable[Path], out: Path, reading: Reading, form: str = "csv",
           progress: Callable[[int], None] | None = None,
           written: list[Path] | None = None, blocks: Iterable[Block] | None = None,
           tables_only: bool = False, refined: Refinement | None = None
           ) -> tuple[list[tuple[Path, Table]], int]:
    """Write the tables of the recordings ``paths`` into ``out``: (path, table) of each
    node's table, in the order first seen, and the number of marks (in ``marks.csv``).
    Each table written whole is added to ``written`` as it is. What reading skipped is
    in ``reading``. RecordingError for a message that is not a record's JSON object;
    MissingExtra for a format whose extra is not installed (Parquet: pyarrow, .mat:
    scipy); on any error, or Ctrl-C, no table that was not whole is left. ``blocks``: the
    messages to export (a window of the recordings, :meth:`.window.Reader.blocks`) in
    place of every message of ``paths``. ``progress``: given the bytes of the messages
    as they are read. ``tables_only``: NoTables, and nothing written, if there is
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
    paths = list(paths)
    # a batch at a time: the same tables, 4x faster or more; a refined time is not
    # carried there (the batch is typed from the messages' own JSON, and the losses are
    # counted on their recorded time), so a refined export goes row by row, Parquet too;
    # so does CSV without pyarrow (not a dependency of the gateway's own), and a CSV or
    # .mat export of less than SMALL
    small = form != "parquet" and sum(_size(path) for path in paths) < SMALL
    if refined is None and not small and _batches_possible():
        from .columnexport import BATCH_WRITERS, export_batches
        if form in BATCH_WRITERS:
            return export_batches(paths, out, reading, form, progress, written, blocks,
                                  tables_only)
    out.mkdir(parents=True, exist_ok=True)
    tables: dict[tuple[int, str], tuple[Table, Output]] = {}
    losses: Losses[tuple[Table, Output, list[Any]]] = Losses()
    outputs: list[Output] = []
    marks: Output | None = None
    done = [] if written is None else written
    with kept(outputs, done):  # (finished whole, or discarded)
        for entry in read_all(paths, reading) if blocks is None else entries_of(blocks):
            if progress is not None:
                progress(len(entry.data))
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
                table = Table(*where, payload, refined=refined is not None)
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
    return [(output.path, table) for table, output in tables.values()], (
        marks.rows if marks is not None else 0)


def _write(counted: list[Counted[tuple[Table, Output, list[Any]]]],
           losses: Losses[Any]) -> None:
    """Write rows whose ``lost_before`` is now known."""
    for row in counted:
        table, output, values = row.item
        values[table.lost_at] = row.lost
        output.add(values)
        table.losses.add(row, period=losses.period(table.node, table.record))


def _batches_possible() -> bool:
    """Whether pyarrow, which decodes the batches, and numpy, which picks them out, are
    installed (CSV needs neither: without them it goes row by row)."""
    try:
        parquet_modules()
        import numpy  # noqa: F401
    except (MissingExtra, ImportError):
        return False
    return True


def _size(path: Path) -> int:
    """A recording's bytes (0 if it went meanwhile: reading it says so)."""
    try:
        return path.stat().st_size
    except OSError:
        return 0


__all__ = ["FORMATS", "MissingExtra", "NoTables", "RecordingError", "export"]
