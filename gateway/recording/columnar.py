"""One table's rows as Arrow columns, a batch of messages at a time: the messages'
JSON decoded in one call (``pyarrow.json`` over the batch joined by newlines), each
column taken out whole and typed as :mod:`.parquetfile` types it, exactly as the row
by row path does (:func:`.parquetfile.converted` of :meth:`.tables.Table.row`).

Why: a dict per message, then a list per row, then a column of Python values cost
about 20 us a row; a batch, about 2 us (bench/exportformats.py). Anything the
one-call path does not take exactly as the row path would (a value of another type
than its column's, a list of another length, a matrix not 3 by 3) sends its batch
through the row path: slower, never different.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from . import cells
from .arrowtime import exact_nanoseconds
from .batchsteps import NONE, Rows
from .cells import RowPath
from .columns import Column
from .parquetfile import arrow_schema, converted, parquet_modules


@dataclass
class Batch:
    """A batch of one table's rows: its columns (``lost_before`` still null) and what
    the counting of losses needs of them."""

    table: Any
    """A pyarrow Table in the export's columns and types."""
    rows: Rows


class Columns:
    """How one table's messages become Arrow columns (``fields``: (column, field,
    index) after the leading columns, as :func:`.tables.field_columns` lays them):
    typed as Parquet types them, or, with ``form`` ``csv`` or ``mat``, as the cells that
    format writes (:mod:`.cells`)."""

    def __init__(self, topic: str, columns: list[Column],
                 fields: list[tuple[str, str, int]], leading: tuple[str, ...],
                 form: str = "parquet") -> None:
        self.topic = topic
        self.form = form if form in ("csv", "mat") else "parquet"
        self.pa, _ = parquet_modules()
        import pyarrow.compute
        import pyarrow.json
        self.pc, self.json = pyarrow.compute, pyarrow.json
        self.columns = columns
        self.schema = arrow_schema(self.pa, columns) if self.form == "parquet" else \
            cells.schema(self.pa, self.form, columns, "lost_before")
        self.sources = [(name, -1) for name in leading] + [
            (field, index) for _, field, index in fields]
        """Where each column's value is in a message: a field, and an element of it."""

    def batch(self, messages: list[bytes], counts: list[int]) -> Batch:
        """The messages (one table's JSON objects) as a batch; ``counts``: the node's
        messages so far at each."""
        try:
            table, numbers = self._one_call(messages)
        except RowPath:
            table, numbers = self._row_path(messages)
        device, timer, seq, time = numbers
        return Batch(table, Rows(device, timer, seq, np.array(counts, np.int64), time))

    def _one_call(self, messages: list[bytes]) -> tuple[Any, tuple[np.ndarray, ...]]:
        pa = self.pa
        try:
            joined = b"\n".join(messages)
            # one block, one thread: the batch is small, and threads on a busy machine
            # cost more than they give (1.5x slower in 1 MB blocks, bench/exportformats.py)
            parsed = self.json.read_json(pa.BufferReader(joined), self.json.ReadOptions(
                use_threads=False, block_size=max(1 << 20, len(joined) + 1)))
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            raise RowPath from None
        if parsed.num_rows != len(messages) or (
                self.form == "csv" and not cells.floats_are_floats(pa, self.pc, parsed, joined)):
            raise RowPath
        parsed = parsed.combine_chunks()
        n = parsed.num_rows
        arrays = []
        for column, field, (name, index) in zip(self.columns, self.schema, self.sources,
                                                strict=True):
            value = parsed.column(name).chunk(0) if name in parsed.column_names else \
                pa.nulls(n)
            value = self._element(value, index)
            arrays.append(self._typed(column.kind, field.type, value) if self.form == "parquet"
                          else cells.cell(pa, self.pc, self.form, column.kind, value))
        table = pa.Table.from_arrays(arrays, schema=self.schema)
        return table, (self._floats(parsed, "device_time"), self._ints(parsed, "timer"),
                       self._ints(parsed, "seq"), self._time(parsed))

    def _element(self, value: Any, index: int) -> Any:
        """Element ``index`` of each row's list (row-major in a matrix), or the value."""
        pa, pc = self.pa, self.pc
        kind = value.type
        if index < 0:
            if pa.types.is_list(kind) or pa.types.is_struct(kind):
                raise RowPath
            return value
        if not pa.types.is_list(kind) or value.null_count:
            raise RowPath
        lengths = pc.list_value_length(value)
        if pa.types.is_list(kind.value_type):  # a matrix: 3 rows of 3
            rows = pc.list_flatten(value)
            if (pc.min(lengths).as_py() != 3 or pc.max(lengths).as_py() != 3
                    or rows.null_count or pa.types.is_list(rows.type.value_type)):
                raise RowPath
            cells = pc.list_value_length(rows)
            if pc.min(cells).as_py() != 3 or pc.max(cells).as_py() != 3:
                raise RowPath
            flat = pc.list_flatten(rows)
            return flat.take(pa.array(np.arange(index, len(flat), 9)))
        if pa.types.is_struct(kind.value_type) or (
                len(value) and pc.min(lengths).as_py() <= index):
            raise RowPath
        return pc.list_element(value, index)

    def _typed(self, kind: str, arrow: Any, value: Any) -> Any:
        """A column as :func:`.parquetfile.converted` types its values."""
        pa, pc = self.pa, self.pc
        source = value.type
        if pa.types.is_null(source):
            return pa.nulls(len(value), arrow)
        if kind in ("time", "duration", "float"):
            if not (pa.types.is_floating(source) or pa.types.is_integer(source)):
                raise RowPath
            if pa.types.is_integer(source) and len(value) and pc.max(pc.abs(value)).as_py() \
                    > 2 ** 53:
                raise RowPath  # (an integer a double does not hold exactly)
            seconds = pc.cast(value, pa.float64())
            if kind == "float":  # (an integer past any double, read as an infinity: null)
                return pc.if_else(pc.is_finite(seconds), seconds, None)
            return pc.cast(exact_nanoseconds(pa, pc, seconds), arrow)
        if kind == "text":
            if not pa.types.is_string(source):
                raise RowPath
            return value
        if not pa.types.is_integer(source):
            raise RowPath
        inside = pc.and_(pc.greater_equal(value, _lowest(kind)),
                         pc.less_equal(value, _highest(kind)))
        return pc.cast(pc.if_else(inside, value, None), arrow)

    def _floats(self, parsed: Any, name: str) -> np.ndarray:
        pa, pc = self.pa, self.pc
        if name not in parsed.column_names:
            return np.full(parsed.num_rows, np.nan)
        value = parsed.column(name).chunk(0)
        if not (pa.types.is_floating(value.type) or pa.types.is_integer(value.type)):
            raise RowPath
        return pc.cast(value, pa.float64()).to_numpy(zero_copy_only=False)

    def _ints(self, parsed: Any, name: str) -> np.ndarray:
        pa, pc = self.pa, self.pc
        if name not in parsed.column_names:
            return np.full(parsed.num_rows, NONE, np.int64)
        value = parsed.column(name).chunk(0)
        if pa.types.is_null(value.type):
            return np.full(parsed.num_rows, NONE, np.int64)
        if not pa.types.is_integer(value.type) or (
                len(value) and value.null_count < len(value) and pc.min(value).as_py() < 0):
            raise RowPath
        return pc.fill_null(pc.cast(value, pa.int64()), NONE).to_numpy()

    def _time(self, parsed: Any) -> np.ndarray:
        time = self._floats(parsed, "time")
        return np.where(np.isnan(time), self._floats(parsed, "host_time"), time)

    def _row_path(self, messages: list[bytes]) -> tuple[Any, tuple[np.ndarray, ...]]:
        """The batch as the row by row export takes it (a message that is not a JSON
        object: RecordingError, as there)."""
        from .entry import Entry
        payloads = [Entry(self.topic, 0, 0, data).payload() for data in messages]
        if self.form == "parquet":
            return self.rows(payloads), _numbers(payloads)
        from .tables import element
        values = [[element(p.get(name), index) for p in payloads]
                  for name, index in self.sources]
        return self.pa.Table.from_arrays(cells.row_cells(
            self.pa, self.form, self.columns, values, self.schema), schema=self.schema), \
            _numbers(payloads)

    def rows(self, payloads: list[dict[str, Any]]) -> Any:
        """Decoded messages as a table of the columns, typed value by value as the row
        by row export types them (:func:`.parquetfile.converted`)."""
        from .tables import element
        arrays = [self.pa.array(converted(column.kind, tuple(
            element(p.get(name), index) for p in payloads)), type=field.type)
            for column, field, (name, index) in zip(self.columns, self.schema,
                                                    self.sources, strict=True)]
        return self.pa.Table.from_arrays(arrays, schema=self.schema)


def _numbers(payloads: list[dict[str, Any]]) -> tuple[np.ndarray, ...]:
    """What the counting of losses needs, as :func:`.losses._last` reads it."""
    def real(value: Any) -> float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        try:
            return float(value) if ok and value == value else np.nan
        except OverflowError:  # (an integer past any double, 10**400: no time)
            return np.nan

    def whole(value: Any) -> int:
        ok = isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 2**63
        return value if ok else NONE
    time = [real(p.get("time")) for p in payloads]
    return (np.array([real(p.get("device_time")) for p in payloads]),
            np.array([whole(p.get("timer")) for p in payloads], np.int64),
            np.array([whole(p.get("seq")) for p in payloads], np.int64),
            np.array([t if t == t else real(p.get("host_time"))
                      for t, p in zip(time, payloads, strict=True)]))


def _lowest(kind: str) -> int:
    from .parquetfile import INTEGER_RANGE
    return INTEGER_RANGE[kind][0]


def _highest(kind: str) -> int:
    from .parquetfile import INTEGER_RANGE
    return INTEGER_RANGE[kind][1]
