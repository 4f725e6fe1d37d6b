"""A batch's columns as CSV and .mat cells, a column at a time, exactly as the row by row
export writes each value (:class:`.tables.CsvWriter`, :class:`.matfile.MatWriter`): CSV
a text a cell (a float as Python's ``repr``, an integer in digits, null empty), .mat a
double (NaN for what is not a finite number) or, in a text column, a text.

Why: the row by row CSV and .mat exports cost about 21 us of CPU a row, most of it a
Python object a message and a value; a batch at a time, about 5, reading included
(4.2x and 4.8x: bench/exportformats.py --before, a million rows, issue 44).
What a column cannot tell exactly (a number in a text column, an integer's JSON among
a column of floats: ``1`` or ``1.0``) sends its batch the row path's way
(:class:`RowPath`): slower, never different.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from gateway.common.reading import number

from .arrowtime import exponent
from .columns import Column
from .tables import text_of


class RowPath(Exception):
    """The batch is not one the one-call path takes exactly."""


REPR_LOW, REPR_HIGH = 1e-4, 1e16
"""Python's ``repr`` writes a float with an exponent below the one and from the other;
Arrow's text of a double, with the same digits, positionally there (and with an
exponent for some long ones between): such values are written one at a time."""

def schema(pa: Any, form: str, columns: list[Column], lost_before: str) -> Any:
    """The Arrow schema of a table's cells in ``form`` (``csv``: texts; ``mat``:
    doubles and texts), ``lost_before`` an int64 (it is set after)."""
    def kind(column: Column) -> Any:
        if column.name == lost_before:
            return pa.int64()
        if form == "csv" or column.kind == "text":
            return pa.string()
        return pa.float64()
    return pa.schema([pa.field(c.name, kind(c), metadata={"description": c.meaning,
                                                          "unit": c.unit}) for c in columns])


def cell(pa: Any, pc: Any, form: str, kind: str, value: Any) -> Any:
    """A column of a batch's JSON values (as pyarrow parsed them) as ``form``'s cells."""
    source = value.type
    if pa.types.is_null(source):
        return pa.nulls(len(value), pa.string() if form == "csv" or kind == "text"
                        else pa.float64())
    if form == "csv":
        return _text(pa, pc, value)
    if kind == "text":
        if not pa.types.is_string(source):
            raise RowPath  # (a number's text: 1 or 1.0, which the column cannot tell)
        return pc.fill_null(value, "")
    if pa.types.is_integer(source) or pa.types.is_floating(source):
        # (an integer past 2**53 to its nearest double, as float() takes it; one past
        # any double, read by pyarrow as an infinity, NaN as number() says)
        real = pc.cast(value, pa.float64(), safe=False)
        return pc.if_else(pc.is_finite(real), real, None)
    if pa.types.is_string(source) or pa.types.is_boolean(source):
        return pa.nulls(len(value), pa.float64())  # (no number: NaN, as number() says)
    raise RowPath


def _text(pa: Any, pc: Any, value: Any) -> Any:
    """A column's values as CSV writes each (``repr`` of a float)."""
    source = value.type
    if pa.types.is_string(source):
        return value
    if pa.types.is_boolean(source):
        return pc.if_else(value, "True", "False")
    if pa.types.is_integer(source):
        return pc.cast(value, pa.string())
    if not pa.types.is_floating(source):
        raise RowPath
    text = pc.cast(value, pa.string())
    values = value.to_numpy(zero_copy_only=False)  # (a null: NaN)
    size = np.abs(values)
    whole = np.floor(values) == values  # (repr writes 1.0 where Arrow writes 1)
    if whole.any():
        text = pc.if_else(pa.array(whole), pc.binary_join_element_wise(text, ".0", ""), text)
    odd = (size >= REPR_HIGH) | ((size < REPR_LOW) & (size > 0)) | exponent(pa, pc, text, size)
    if odd.any():
        texts = text.to_pylist()
        for i in np.flatnonzero(odd).tolist():
            texts[i] = repr(value[i].as_py())
        text = pa.array(texts, pa.string())
    return text


def floats_are_floats(pa: Any, pc: Any, parsed: Any, joined: bytes) -> bool:
    """Whether every value of the parsed batch's floating columns was written as a
    float (a point in its JSON), not as an integer: pyarrow reads a column of ``1`` and
    ``1.5`` as doubles, where CSV, as the row path writes it, says ``1``. Told by
    counting: each number written as a float has one point, so the points of the JSON
    (less those inside its texts) are as many as the floating values only if none was
    written as an integer. (An exponent without a point, a point escaped in a text, or a
    point in a name make them differ too: the row path's way, never a wrong cell.)"""
    if any("." in name for name in _names(pa, parsed.schema)):
        return False
    floats = texts = 0
    for array in _leaves(pa, parsed.columns):
        if pa.types.is_floating(array.type):
            floats += len(array) - array.null_count
        elif pa.types.is_string(array.type) and len(array) - array.null_count:
            texts += pc.sum(pc.count_substring(array, ".")).as_py() or 0
    return joined.count(b".") - texts == floats


def _names(pa: Any, schema: Any) -> Iterable[str]:
    for field in schema:
        yield field.name
        kind = field.type
        while pa.types.is_list(kind):
            kind = kind.value_type
        if pa.types.is_struct(kind):
            yield from _names(pa, kind)


def _leaves(pa: Any, arrays: Iterable[Any]) -> Iterable[Any]:
    """The arrays of values inside columns (a list's items, a struct's fields)."""
    for array in arrays:
        if hasattr(array, "chunks"):
            yield from _leaves(pa, array.chunks)
        elif pa.types.is_list(array.type):
            yield from _leaves(pa, [array.flatten()])
        elif pa.types.is_struct(array.type):
            yield from _leaves(pa, [array.field(i) for i in range(array.type.num_fields)])
        else:
            yield array


def row_cells(pa: Any, form: str, columns: list[Column], values: list[list[Any]],
              target: Any) -> list[Any]:
    """The row path's values (a column's list each) as ``form``'s cells, typed as
    ``target`` (the cells' schema)."""
    arrays = []
    for column, field, column_values in zip(columns, target, values, strict=True):
        if pa.types.is_int64(field.type):  # (lost_before: set after)
            arrays.append(pa.nulls(len(column_values), pa.int64()))
        elif form == "csv":
            arrays.append(pa.array([text_of(v) for v in column_values], pa.string()))
        elif column.kind == "text":
            arrays.append(pa.array(["" if v is None else str(v) for v in column_values],
                                   pa.string()))
        else:
            arrays.append(pa.array([np.nan if (real := number(v)) is None else real
                                    for v in column_values], pa.float64()))
    return arrays
