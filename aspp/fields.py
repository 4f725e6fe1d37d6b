"""Field types: how one named quantity sits in a GX2 record, and how it reads in Python.

A record layout is a sequence of these; :mod:`aspp.records` compiles each layout into one
``struct.Struct`` so a record is unpacked in a single call, then shapes the flat values
into the contract's forms (3-vectors as 3 floats, matrices as 3 rows of 3, text).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .errors import CommandError

Vector = tuple[float, float, float]
Matrix = tuple[Vector, Vector, Vector]
Value = int | float | str | Vector | Matrix | tuple[int, ...]


@dataclass(frozen=True)
class FieldType:
    """One kind of quantity: its struct code, how many struct items it takes, its shape."""

    name: str
    code: str
    items: int
    shape: str  # "int", "float", "vector", "matrix", "ints", "text"

    @property
    def size(self) -> int:
        """Bytes on the wire."""
        return struct.calcsize(">" + self.code)

    @property
    def max_int(self) -> int:
        """Largest value of an integer field (each element, for ``ints``)."""
        return (1 << (8 * struct.calcsize(">" + self.code[-1]))) - 1

    def shape_items(self, items: Sequence[object]) -> Value:
        """Turn the struct items of this field into its Python value."""
        if self.shape == "vector":
            return tuple(items)  # type: ignore[return-value]
        if self.shape == "matrix":
            return (tuple(items[0:3]), tuple(items[3:6]), tuple(items[6:9]))  # type: ignore[return-value]
        if self.shape == "ints":
            return tuple(items)  # type: ignore[return-value]
        if self.shape == "text":
            raw = items[0]
            assert isinstance(raw, bytes)
            return raw.decode("latin-1").rstrip(" \x00")
        return items[0]  # type: ignore[return-value]

    def flatten(self, name: str, value: object) -> tuple[object, ...]:
        """The struct items for ``value``; raises CommandError naming ``name`` if it
        does not have this field's shape."""
        if self.shape == "int":
            return (self._bounded(name, _number(name, value, True)),)
        if self.shape == "float":
            return (_number(name, value, False),)
        if self.shape == "text":
            if not isinstance(value, str):
                raise CommandError(f"{name} must be a string, not {value!r}")
            try:
                encoded = value.encode("latin-1")
            except UnicodeEncodeError:
                raise CommandError(f"{name} must be plain text: {value!r}") from None
            if len(encoded) > 16:
                raise CommandError(f"{name} is longer than 16 characters: {value!r}")
            return (encoded.ljust(16, b" "),)
        if self.shape == "matrix":
            _check_length(name, value, 3)
            return tuple(v for i, row in enumerate(value)  # type: ignore[arg-type]
                         for v in _numbers(f"{name}[{i}]", row, 3, False))
        if self.shape == "ints":
            return tuple(self._bounded(f"{name}[{i}]", v) for i, v in
                         enumerate(_numbers(name, value, self.items, True)))
        return _numbers(name, value, self.items, False)

    def _bounded(self, name: str, value: int | float) -> int | float:
        if not 0 <= value <= self.max_int:
            raise CommandError(f"{name} {value} is out of range 0..{self.max_int}")
        return value


def _number(name: str, value: object, integer: bool) -> int | float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CommandError(f"{name} must be a number, not {value!r}")
    if integer:
        if isinstance(value, float):
            if not value.is_integer():
                raise CommandError(f"{name} must be a whole number, not {value!r}")
            value = int(value)
        return value
    return float(value)


def _check_length(name: str, value: object, length: int) -> None:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise CommandError(f"{name} must be a sequence of {length}, not {value!r}")
    if len(value) != length:
        raise CommandError(f"{name} must have {length} elements, not {len(value)}")


def _numbers(name: str, value: object, length: int, integer: bool) -> tuple[int | float, ...]:
    _check_length(name, value, length)
    return tuple(_number(f"{name}[{i}]", v, integer)
                 for i, v in enumerate(value))  # type: ignore[arg-type]


U8 = FieldType("u8", "B", 1, "int")
U16 = FieldType("u16", "H", 1, "int")
U32 = FieldType("u32", "I", 1, "int")
F32 = FieldType("f32", "f", 1, "float")
VEC3 = FieldType("vec3", "3f", 3, "vector")
MAT3 = FieldType("mat3", "9f", 9, "matrix")
TEMPS4 = FieldType("4 x u16", "4H", 4, "ints")
TEXT16 = FieldType("16 chars", "16s", 1, "text")
TIMER = FieldType("timer", "I", 1, "int")
QUAT4 = FieldType("quaternion", "4f", 4, "vector")
"""A quaternion (w, x, y, z): never on the wire, the gateway computes it
(:data:`aspp.records.DERIVED`)."""

Check = Callable[[str, object], None]


@dataclass(frozen=True)
class Field:
    """A named quantity in a request or a reply. ``check`` validates a request
    argument beyond its type (its range, its allowed values).

    ``doc`` is its unit, then what it is: ``"UNIT; MEANING"``, the unit followed by
    the names of a list's elements where they are not x, y, z (``"A/D codes: accel,
    gyro_x, gyro_y, gyro_z; temperature sensor outputs"``); a doc without ``;`` is a
    meaning alone (a count, a code, text). The plots label their axes with the unit,
    and the recordings' JSON Schemas describe each field with both.
    """

    name: str
    type: FieldType
    doc: str = ""
    check: Check | None = None

    @property
    def unit(self) -> str:
        """``"g"``, ``"rad/s"``, ...; empty for a quantity without a unit."""
        return self._unit_part.partition(":")[0].strip()

    @property
    def elements(self) -> tuple[str, ...]:
        """The names of a list's elements, where the doc gives them."""
        named = self._unit_part.partition(":")[2]
        return tuple(name.strip() for name in named.split(",")) if named else ()

    @property
    def meaning(self) -> str:
        return self.doc.partition(";")[2].strip() if ";" in self.doc else self.doc

    @property
    def _unit_part(self) -> str:
        return self.doc.partition(";")[0] if ";" in self.doc else ""


@dataclass(frozen=True)
class Const:
    """Bytes a request must carry verbatim: the confirmation bytes (C1 29, B7 44, ...)
    that guard against a stray byte being taken for a command."""

    value: bytes


def in_range(low: int, high: int) -> Check:
    def check(name: str, value: object) -> None:
        if not low <= value <= high:  # type: ignore[operator]
            raise CommandError(f"{name} {value} is out of range {low}..{high}")
    return check


def one_of(allowed: dict[int, str]) -> Check:
    def check(name: str, value: object) -> None:
        if value not in allowed:
            choices = ", ".join(f"{k} ({v})" for k, v in allowed.items())
            raise CommandError(f"{name} {value} is not one of {choices}")
    return check


def finite(name: str, value: object) -> None:
    for i, v in enumerate(value):  # type: ignore[arg-type]
        if not math.isfinite(v):
            raise CommandError(f"{name}[{i}] must be a finite number, not {v!r}")
