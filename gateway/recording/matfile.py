"""A table as a MATLAB ``.mat`` file (version 5, what scipy's ``savemat`` writes and
MATLAB and GNU Octave ``load``): one struct named after the table, a column vector a
field, and beside them ``units`` and ``descriptions``, structs with a text a column
(a column whose name MATLAB cannot take, or that two columns would share, is renamed:
:func:`field_names`).

Numbers are doubles (NaN where a value is missing), times UNIX seconds as in the
messages (MATLAB: ``datetime(t, 'ConvertFrom', 'posixtime')``), text columns cell
arrays. ``savemat`` writes a whole struct at once, so a table's columns are held in
memory until it is written: 8 bytes a number (an ``array('d')``).
"""

from __future__ import annotations

import re
from array import array
from pathlib import Path
from typing import Any

from gateway.common.reading import number

from .columns import Column
from .parquetfile import MissingExtra

INSTALL_MAT = "pip install 'gx2-gateway[mat]'"
MATLAB_NAME = 63
"""MATLAB's longest variable or field name (namelengthmax)."""


def mat_modules() -> tuple[Any, Any]:
    try:
        import numpy
        import scipy.io
    except ImportError:
        raise MissingExtra(f".mat export needs scipy: {INSTALL_MAT}") from None
    return numpy, scipy.io


def matlab_name(text: str, prefix: str = "n") -> str:
    """A name MATLAB takes: letters, digits and ``_``, a letter first (``prefix``
    before one that does not start with a letter): ``76_accel_angrate`` ->
    ``n76_accel_angrate``, the struct of that table. A known record's columns are
    such names already; a foreign record's may not be."""
    name = re.sub(r"\W", "_", text, flags=re.ASCII)
    if not name[:1].isalpha():
        name = f"{prefix}{name}"
    return name[:MATLAB_NAME]


RESERVED = ("units", "descriptions")
"""The struct's fields beside the columns."""


def field_names(columns: list[Column]) -> list[str]:
    """Each column's field name: its MATLAB name, made unique with a suffix (``_2``,
    ``_3`` ..) where two names become one (``a-b`` and ``a_b``) or a column would
    take a name of RESERVED: every column is kept."""
    taken = set(RESERVED)
    names = []
    for column in columns:
        name = base = matlab_name(column.name, "f")
        count = 1
        while name in taken:
            count += 1
            suffix = f"_{count}"
            name = base[:MATLAB_NAME - len(suffix)] + suffix
        taken.add(name)
        names.append(name)
    return names


class MatWriter:
    def __init__(self, path: Path, columns: list[Column]) -> None:
        self._numpy, self._io = mat_modules()
        self._path, self._columns = path, columns
        self._values: list[Any] = [[] if c.kind == "text" else array("d")
                                   for c in columns]
        path.touch()

    def add(self, row: list[Any]) -> None:
        for column, values, value in zip(self._columns, self._values, row, strict=True):
            if column.kind == "text":
                values.append("" if value is None else str(value))
            else:  # (an integer beyond a double, 10**400, is missing as text is)
                real = number(value)
                values.append(float("nan") if real is None else real)

    def add_columns(self, columns: list[Any]) -> None:
        """Rows a column at a time: a list of texts for a text column, else an array of
        doubles (NaN: missing), as :meth:`add` would have made them."""
        for column, values, given in zip(self._columns, self._values, columns, strict=True):
            if column.kind == "text":
                values.extend(given)
            else:
                values.frombytes(self._numpy.ascontiguousarray(given, "<f8").tobytes())

    def close(self) -> None:
        np = self._numpy
        names = field_names(self._columns)
        struct: dict[str, Any] = {}
        for name, column, values in zip(names, self._columns, self._values, strict=True):
            if column.kind == "text":
                struct[name] = np.array(values, dtype=object).reshape(-1, 1)
            else:
                struct[name] = np.frombuffer(values, dtype=np.float64).reshape(-1, 1)
        struct["units"] = {n: c.unit for n, c in zip(names, self._columns, strict=True)}
        struct["descriptions"] = {n: c.meaning
                                  for n, c in zip(names, self._columns, strict=True)}
        # the table's name: the file's, without export's temporary dot and suffixes
        name = matlab_name(self._path.name.removeprefix(".").split(".")[0])
        with self._path.open("wb") as file:
            self._io.savemat(file, {name: struct}, long_field_names=True,
                             do_compression=False, oned_as="column")
