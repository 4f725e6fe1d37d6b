"""A table as export writes it, row by row (:mod:`.export`) or a batch at a time
(:mod:`.columnexport`): its columns, its name, the writer of each table format, its
file written under a temporary name and renamed when whole. Below both exports, so
that neither imports the other round a loop (tests/ctl/test_imports.py)."""

from __future__ import annotations

import contextlib
import csv
import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from aspp.records import BY_NAME, derived

from .columns import Column, record_columns
from .matfile import MatWriter
from .parquetfile import ParquetWriter
from .summary import Summary

if TYPE_CHECKING:
    from .marks import Mark

LEADING = ("time", "host_time", "device_time", "seq", "lost_before", "lqi", "rssi")
PLACED = "time_placed"
BOUND = "time_bound_ms"
REFINED_LEADING = (LEADING[0], PLACED, BOUND, *LEADING[1:])
"""With ``time`` refined after the fact (:mod:`.refined`): how each row's time was
placed, and its bound, beside it."""
BOOKKEEPING = frozenset((*REFINED_LEADING, "node", "record", "command"))
AXES = ("x", "y", "z")
MATRIX = tuple(f"{row}{column}" for row in (1, 2, 3) for column in (1, 2, 3))
MARKS = "marks"
TEMPORARY = ".{name}.partial"


def table_name(address: int, record: str, form: str) -> str:
    """The name of a node's table of ``record`` in format ``form``."""
    return f"{address}_{record}.{form}"


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
                 refined: bool = False) -> None:
        self.node, self.record = node, record
        self.leading = REFINED_LEADING if refined else LEADING
        """Its columns before the record's fields (``refined``: with ``time_placed`` and
        ``time_bound_ms`` after ``time``)."""
        self.lost_at = self.leading.index("lost_before")
        self.fields = field_columns(record, first)
        self.columns = record_columns(record, self.leading, self.fields, first)
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


def text_of(value: Any) -> str | None:
    """A value as a CSV cell holds it: a float as repr (it reads back to the same
    float), None (null, NaN) an empty cell, anything else as str."""
    if value is None:
        return None
    return repr(value) if isinstance(value, float) else str(value)


class CsvWriter(Writer):
    def __init__(self, path: Path, columns: list[Column]) -> None:
        self._file: IO[str] = path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow([column.name for column in columns])

    def add(self, row: list[Any]) -> None:
        self._csv.writerow([text_of(v) for v in row])  # (csv writes None as "")

    def close(self) -> None:
        self._file.close()


WRITERS: dict[str, Callable[[Path, list[Column]], Writer]] = {
    "csv": CsvWriter, "parquet": ParquetWriter, "mat": MatWriter}
"""Each table format's writer of a table's rows (every format: :data:`.export.FORMATS`)."""


class Output:
    """One table's file: written under its temporary name, renamed when whole."""

    def __init__(self, out: Path, name: str, form: str, columns: list[Column],
                 outputs: list[Output], make: Callable[[Path], Any] | None = None) -> None:
        self.path = out / name
        self.temporary = out / TEMPORARY.format(name=name)
        self.rows = 0
        self._writer: Writer | None = None
        # known to the export's clean-up before its file exists: a Ctrl-C that lands
        # just after the file is made (as a test's does, sent when a file appears) would
        # otherwise leave the temporary behind
        outputs.append(self)
        self._writer = (make or (lambda path: WRITERS[form](path, columns)))(self.temporary)

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


@contextlib.contextmanager
def kept(outputs: list[Output], done: list[Path]) -> Iterator[None]:
    """Every output finished (and listed in ``done``) when the block ends whole; on an
    error, each not yet finished discarded: no table is left half written under its
    name."""
    try:
        yield
        for output in outputs:
            output.finish()
            done.append(output.path)
    finally:
        for output in outputs:
            if output.path not in done:
                output.discard()


class NoTables(Exception):
    """An export that found marks but no table where tables were asked for."""


def mark_row(mark: Mark) -> list[Any]:
    return [mark.time, mark.host_time, " ".join(map(str, mark.nodes)), mark.text]
