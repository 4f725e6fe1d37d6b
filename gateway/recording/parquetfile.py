"""A table as Parquet: its schema fixed by its columns' kinds before the first row, times
as ``timestamp[ns, UTC]``, the node's timer as ``duration[ns]``, each field's meaning
and unit in its Arrow field metadata (``description``, ``unit``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gateway.common.reading import number

from .columns import Column, nanoseconds

INSTALL_PARQUET = "pip install 'gx2-gateway[parquet]'"
BATCH = 10_000
"""Rows held before they are written as a row group."""
INTEGER_RANGE = {"uint8": (0, 0xFF), "uint16": (0, 0xFFFF), "uint32": (0, 0xFFFF_FFFF),
                 "int8": (-0x80, 0x7F), "int64": (-(2**63), 2**63 - 1)}


class MissingExtra(Exception):
    """An optional dependency is not installed: one line saying how to install it."""


def parquet_modules() -> tuple[Any, Any]:
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise MissingExtra(f"Parquet export needs pyarrow: {INSTALL_PARQUET}") from None
    return pyarrow, pyarrow.parquet


def arrow_schema(pa: Any, columns: list[Column]) -> Any:
    def field(column: Column) -> Any:
        metadata = {"description": column.meaning, "unit": column.unit}
        return pa.field(column.name, _arrow_type(pa, column.kind), metadata=metadata)
    return pa.schema([field(column) for column in columns])


def _arrow_type(pa: Any, kind: str) -> Any:
    if kind == "time":
        return pa.timestamp("ns", tz="UTC")
    if kind == "duration":
        return pa.duration("ns")
    if kind == "float":
        return pa.float64()
    if kind == "text":
        return pa.string()
    return getattr(pa, kind)()


def converted(kind: str, values: tuple[Any, ...]) -> list[Any]:
    """A column's values as its Arrow type takes them; None for a value that is not of
    its kind or beyond what the type holds (null in the file, as an empty cell in CSV;
    a float that is not finite is null too)."""
    if kind in ("time", "duration"):
        # (a timestamp[ns] is an int64: the years 1677 to 2262; a foreign recording's
        # time in ms, or 1e10 s, is beyond it: null, as a value not of its kind)
        low, high = INTEGER_RANGE["int64"]
        return [t if t is not None and low <= t <= high else None
                for t in map(nanoseconds, values)]
    if kind == "float":
        return [number(v) for v in values]
    if kind == "text":
        return [v if isinstance(v, str) else None for v in values]
    low, high = INTEGER_RANGE[kind]
    return [v if isinstance(v, int) and not isinstance(v, bool) and low <= v <= high
            else None for v in values]


class ParquetWriter:
    def __init__(self, path: Path, columns: list[Column]) -> None:
        self._pa, pq = parquet_modules()
        self._columns = columns
        self._schema = arrow_schema(self._pa, columns)
        self._rows: list[list[Any]] = []
        self._writer = pq.ParquetWriter(path, self._schema)

    def add(self, row: list[Any]) -> None:
        self._rows.append(row)
        if len(self._rows) >= BATCH:
            self._flush()

    def _flush(self) -> None:
        if not self._rows:
            return
        arrays = [self._pa.array(converted(column.kind, values), type=field.type)
                  for column, field, values in zip(self._columns, self._schema,
                                                   zip(*self._rows, strict=True),
                                                   strict=True)]
        self._writer.write_table(self._pa.Table.from_arrays(arrays, schema=self._schema))
        self._rows = []

    def close(self) -> None:
        self._flush()
        self._writer.close()
