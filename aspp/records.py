"""THE table of GX2 commands and their reply records, and the reply codec it drives.

One row per command: its byte, the contract's record name, the request layout (the
confirmation bytes and the arguments after the command byte) and the reply layout
(the fields after the echo byte). Decoding, encoding, lookup by name or byte, command
building and parsing (:mod:`aspp.commands`) and the documentation all read this table.

A reply record here is the wired record without its trailing checksum, echo byte first:
exactly the ``m`` bytes an ASPP reply packet carries.
"""

from __future__ import annotations

import difflib
import math
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from operator import itemgetter
from typing import NamedTuple

from .errors import CommandError, RecordError
from .events import type_strict
from .fields import (
    F32,
    MAT3,
    QUAT4,
    TEMPS4,
    TEXT16,
    TIMER,
    U8,
    U16,
    U32,
    VEC3,
    Const,
    Field,
    Value,
    finite,
    in_range,
    one_of,
)

_AS_SLICE = frozenset(("vector", "ints"))
"""Field shapes whose value is a slice of the unpacked items (a slice of a tuple is a
tuple); a value of an _AS_ITEM shape is a single item."""
_AS_ITEM = frozenset(("int", "float"))

CONFIRM = Const(b"\xC1\x29")
"""The confirmation bytes most state-changing commands need."""


@dataclass(frozen=True)
class CommandSpec:
    """One GX2 command and the record it answers with (``reply`` None: no reply)."""

    code: int
    name: str
    title: str
    request: tuple[Const | Field, ...] = ()
    reply: tuple[Field, ...] | None = ()
    streamable: bool = False
    reply_may_run_long: bool = False
    """The reference's length for this reply is wrong (0xFB); accept extra bytes."""

    reply_struct: struct.Struct = field(init=False, repr=False, compare=False)
    """The reply layout compiled: the echo byte, then every field, big-endian."""
    field_names: tuple[str, ...] = field(init=False, repr=False, compare=False)
    """The reply's field names in order (computed once: used for every record)."""
    request_struct: struct.Struct = field(init=False, repr=False, compare=False)
    reply_slices: tuple[tuple[int, int, Field], ...] = field(init=False, repr=False,
                                                            compare=False)
    """Where each reply field's items sit in the unpacked tuple (computed once)."""
    reply_getter: Callable[[tuple], tuple] | None = field(init=False, repr=False,
                                                          compare=False)
    """Groups the unpacked items into the field values in one C call, for a layout of
    two or more fields that are all scalars or flat tuples (every streamed record but
    those holding a matrix); None: :func:`shape` groups them field by field."""

    def __repr__(self) -> str:
        return f"CommandSpec(0x{self.code:02X}, {self.name!r})"

    def __post_init__(self) -> None:
        reply_codes = "".join(f.type.code for f in self.reply or ())
        request_codes = "".join(f"{len(item.value)}s" if isinstance(item, Const)
                                else item.type.code for item in self.request)
        object.__setattr__(self, "reply_struct", struct.Struct(">B" + reply_codes))
        object.__setattr__(self, "request_struct", struct.Struct(">B" + request_codes))
        object.__setattr__(self, "field_names", tuple(f.name for f in self.reply or ()))
        slices, at = [], 1  # after the echo byte
        for f in self.reply or ():
            slices.append((at, at + f.type.items, f))
            at += f.type.items
        object.__setattr__(self, "reply_slices", tuple(slices))
        flat = len(slices) >= 2 and all(f.type.shape in _AS_SLICE | _AS_ITEM
                                        for _, _, f in slices)
        object.__setattr__(self, "reply_getter", itemgetter(*(
            slice(start, stop) if f.type.shape in _AS_SLICE else start
            for start, stop, f in slices)) if flat else None)

    @property
    def reply_size(self) -> int | None:
        """Bytes in the reply record (echo byte included), or None for no reply."""
        return None if self.reply is None else self.reply_struct.size

    @property
    def request_size(self) -> int:
        """Bytes in the command (command byte included)."""
        return self.request_struct.size

    @property
    def arguments(self) -> tuple[Field, ...]:
        return tuple(item for item in self.request if isinstance(item, Field))

    @property
    def pollable(self) -> bool:
        """Answers a bare command byte with a record (what ``gx2ctl poll`` sends)."""
        return not self.request and self.reply is not None

    @property
    def timed(self) -> bool:
        return self.reply is not None and any(f.name == "timer" for f in self.reply)


def _timed(*fields: Field) -> tuple[Field, ...]:
    return (*fields, Field("timer", TIMER, "ticks; the node's timer: 19,660,800 ticks "
                           "a second since power-up, wrapping every 218.45 s"))


_ACCEL = Field("accel", VEC3, "g; acceleration x, y, z, sensor frame")
_ANG_RATE = Field("ang_rate", VEC3, "rad/s; angular rate x, y, z, sensor frame")
_MAG = Field("mag", VEC3, "gauss; magnetic field x, y, z, sensor frame; NaN on an "
             "Inertia-Link (no magnetometer)")
_ORIENTATION = Field("orientation", MAT3, "orientation matrix M, earth to sensor frame, "
                     "row-major")
_DELTA_ANGLE = Field("delta_angle", VEC3, "rad; angle turned about x, y, z over the "
                     "record's interval, sensor frame")
_DELTA_VELOCITY = Field("delta_velocity", VEC3, "g*s; velocity change along x, y, z over "
                        "the record's interval, sensor frame")
_EULER = (Field("roll", F32, "rad; roll angle"), Field("pitch", F32, "rad; pitch angle"),
          Field("yaw", F32, "rad; yaw angle"))
_ACCEL_BIAS = "g; accelerometer bias correction x, y, z"
_GYRO_BIAS = "rad/s; gyro bias correction x, y, z"
_U16_ARG = in_range(0, 0xFFFF)

_SPECS = (
    CommandSpec(0xC1, "raw_sensors", "Raw accelerometer and angular rate sensor outputs",
                reply=_timed(Field("raw_accel", VEC3,
                                   "A/D codes; raw accelerometer outputs x, y, z"),
                             Field("raw_ang_rate", VEC3, "A/D codes; raw angular rate sensor "
                                   "outputs x, y, z")), streamable=True),
    CommandSpec(0xC2, "accel_angrate", "Acceleration and angular rate",
                reply=_timed(_ACCEL, _ANG_RATE), streamable=True),
    CommandSpec(0xC3, "delta_angle_velocity", "Delta angle and delta velocity",
                reply=_timed(_DELTA_ANGLE, _DELTA_VELOCITY), streamable=True),
    CommandSpec(0xC4, "continuous_mode", "Set continuous mode",
                request=(CONFIRM, Field("continuous_command", U8,
                                        "record to stream, 0 to stop")),
                reply=_timed(Field("continuous_command", U8, "the command byte of the "
                                   "record now streamed, 0 for none"))),
    CommandSpec(0xC5, "orientation", "Orientation matrix",
                reply=_timed(_ORIENTATION), streamable=True),
    CommandSpec(0xC6, "orientation_update", "Orientation update matrix",
                reply=_timed(Field("orientation_update", MAT3, "orientation update "
                                   "matrix C, row-major")),
                streamable=True),
    CommandSpec(0xC7, "mag", "Scaled magnetometer vector",
                reply=_timed(_MAG), streamable=True),
    CommandSpec(0xC8, "accel_angrate_orientation",
                "Acceleration, angular rate and orientation matrix",
                reply=_timed(_ACCEL, _ANG_RATE, _ORIENTATION), streamable=True),
    CommandSpec(0xC9, "accel_bias", "Write accelerometer bias correction",
                request=(Const(b"\xB7\x44"), Field("accel_bias", VEC3, _ACCEL_BIAS, finite)),
                reply=_timed(Field("accel_bias", VEC3, _ACCEL_BIAS))),
    CommandSpec(0xCA, "gyro_bias", "Write gyro bias correction",
                request=(Const(b"\x12\xA5"), Field("gyro_bias", VEC3, _GYRO_BIAS, finite)),
                reply=_timed(Field("gyro_bias", VEC3, _GYRO_BIAS))),
    CommandSpec(0xCB, "accel_angrate_mag", "Acceleration, angular rate and magnetometer",
                reply=_timed(_ACCEL, _ANG_RATE, _MAG), streamable=True),
    CommandSpec(0xCC, "accel_angrate_mag_orientation",
                "Acceleration, angular rate, magnetometer and orientation matrix",
                reply=_timed(_ACCEL, _ANG_RATE, _MAG, _ORIENTATION), streamable=True),
    CommandSpec(0xCD, "capture_gyro_bias", "Capture gyro bias",
                request=(CONFIRM, Field("sampling_time", U16, "ms; 10000..30000 advised",
                                        in_range(1, 0xFFFF))),
                reply=_timed(Field("gyro_bias", VEC3, "rad/s; gyro bias x, y, z captured"))),
    CommandSpec(0xCE, "euler", "Euler angles", reply=_timed(*_EULER), streamable=True),
    CommandSpec(0xCF, "euler_angrate", "Euler angles and angular rates",
                reply=_timed(*_EULER, _ANG_RATE), streamable=True),
    CommandSpec(0xD0, "store_nonvolatile", "Transfer quantity to non-volatile memory",
                request=(CONFIRM, Field("quantity", U16, "1 accel bias, 2 gyro bias",
                                        one_of({1: "accel bias", 2: "gyro bias"}))),
                reply=_timed(Field("quantity", U16, "what was stored (1 accel bias, "
                                   "2 gyro bias, 0xFFFF nothing)"))),
    CommandSpec(0xD1, "temperatures", "Temperatures",
                reply=_timed(Field("temperature", TEMPS4, "A/D codes: accel, gyro_x, gyro_y, "
                                   "gyro_z; temperature sensor outputs")),
                streamable=True),
    CommandSpec(0xD2, "stab_accel_angrate_mag",
                "Gyro-stabilised acceleration, angular rate and magnetometer",
                reply=_timed(Field("stab_accel", VEC3, "g; gyro-stabilised acceleration x, "
                                   "y, z, sensor frame"), _ANG_RATE,
                             Field("stab_mag", VEC3, "gauss; gyro-stabilised magnetic field "
                                   "x, y, z, sensor frame")), streamable=True),
    CommandSpec(0xD3, "delta_angle_velocity_mag",
                "Delta angle, delta velocity and magnetometer",
                reply=_timed(_DELTA_ANGLE, _DELTA_VELOCITY, _MAG), streamable=True),
    CommandSpec(0xE4, "eeprom_write", "Write word to EEPROM",
                request=(Const(b"\xC1\x29\x00"), Field("address", U16, "", _U16_ARG),
                         Field("value", U16, "", _U16_ARG)),
                reply=(Field("value", U16, "the word now stored at the address"),)),
    CommandSpec(0xE5, "eeprom_read", "Read word from EEPROM",
                request=(Const(b"\x00"), Field("address", U16, "", _U16_ARG)),
                reply=(Field("value", U16, "the word stored at the address"),)),
    CommandSpec(0xE9, "firmware_version", "Read firmware version number",
                reply=(Field("version", U32, "firmware version number"),)),
    CommandSpec(0xEA, "device_id", "Read device identifier string",
                request=(Field("selector", U8, "0 model number, 1 serial number, "
                               "2 model name, 3 device options", in_range(0, 3)),),
                reply=(Field("selector", U8, "which string (0 model number, 1 serial "
                             "number, 2 model name, 3 device options)"),
                       Field("text", TEXT16, "the string (trailing spaces and NULs "
                             "stripped)"))),
    CommandSpec(0xFA, "stop_continuous", "Stop continuous mode (no reply)", reply=None),
    CommandSpec(0xFB, "built_in_test", "Built-in test",
                request=(CONFIRM, Field("test_config", U8, "BIT bits 2..5 (0 ends BIT)")),
                reply=(Field("test_config", U8, "the built-in test configuration "
                             "(BIT bits 2..5)"),), reply_may_run_long=True),
)

_QUATERNION = Field("quaternion", QUAT4, ": w, x, y, z; unit quaternion of the sensor's "
                    "orientation in the earth frame (the rotation of M's transpose, as "
                    "roll, pitch, yaw), w >= 0")
DERIVED_FROM_MATRIX = (*_EULER, _QUATERNION)
"""Fields the gateway adds to every record with an orientation matrix, computed from it
(:mod:`aspp.orientation`), so that a subscriber, PlotJuggler or a table needs no
conversion: the same roll, pitch, yaw as the node's euler record, and the quaternion."""
ORIENTED: frozenset[str] = frozenset(
    spec.name for spec in _SPECS if spec.reply and _ORIENTATION in spec.reply)
"""The records with an orientation matrix: those that carry DERIVED_FROM_MATRIX."""


def derived(spec: CommandSpec) -> tuple[Field, ...]:
    """The fields the gateway adds to ``spec``'s record as published, after its own."""
    return DERIVED_FROM_MATRIX if spec.name in ORIENTED else ()


BY_CODE: dict[int, CommandSpec] = {spec.code: spec for spec in _SPECS}
BY_NAME: dict[str, CommandSpec] = {spec.name: spec for spec in _SPECS}
STREAMABLE: frozenset[int] = frozenset(s.code for s in _SPECS if s.streamable)


def all_specs() -> Iterator[CommandSpec]:
    """Every command, in command-byte order."""
    return iter(_SPECS)


def lookup(record: str | int, among: Iterable[str] | None = None) -> CommandSpec:
    """The command for a record name (``"euler"``), a byte (``0xCE``) or ``"0xCE"``.
    ``among``: the names an unknown one is said to be none of (and may be a typo of):
    those that fit where it was given (default: every record)."""
    if isinstance(record, str):
        text = record.strip()
        if text.lower().startswith("0x"):
            try:
                record = int(text, 16)
            except ValueError:
                raise RecordError(f"{record!r} is not a hexadecimal command byte") from None
        elif text in BY_NAME:
            return BY_NAME[text]
        else:
            names = list(BY_NAME if among is None else among)
            close = difflib.get_close_matches(text, names, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise RecordError(f"unknown record {record!r}; {hint}known: "
                              f"{', '.join(names)}")
    if isinstance(record, bool) or not isinstance(record, int):
        raise RecordError(f"a record is a name or a command byte, not {record!r}")
    try:
        return BY_CODE[record]
    except KeyError:
        raise RecordError(f"0x{record:02X} is not a GX2 command with a record") from None


def checked(record: str | int, *, streamable: bool = False,
            pollable: bool = False) -> CommandSpec:
    """:func:`lookup`, then check the record can be streamed in continuous mode or
    polled with a bare command byte; RecordError (a ValueError) names what is wrong
    (an unknown name, with the records that could be given there: issue 43 listed
    ``eeprom_write`` to a stream)."""
    among = None
    if streamable or pollable:
        among = [spec.name for spec in _SPECS
                 if (not streamable or spec.code in STREAMABLE)
                 and (not pollable or spec.pollable)]
    spec = lookup(record, among)
    if streamable and spec.code not in STREAMABLE:
        raise RecordError(f"{spec.name} cannot be streamed in continuous mode")
    if pollable and not spec.pollable:
        raise RecordError(f"{spec.name} cannot be polled (it takes arguments or has no "
                          "reply)")
    return spec


@type_strict
class Record(NamedTuple):
    """One decoded reply record: its command and its field values, in table order.

    A NamedTuple rather than a frozen dataclass for the events' reason: one is made
    for every record, and a tuple is several times cheaper to build. ``record["timer"]``
    reads a field by name; a Record equals only a Record.
    """

    spec: CommandSpec
    values: tuple[Value, ...]

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in self.as_dict().items())
        return f"Record({self.spec.name}: {fields})"

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def command(self) -> int:
        return self.spec.code

    @property
    def timer(self) -> int | None:
        return self["timer"] if self.spec.timed else None  # type: ignore[return-value]

    def __getitem__(self, field_name: str) -> Value:  # type: ignore[override]
        if not isinstance(field_name, str):  # the tuple's own indexing, for its own use
            return tuple.__getitem__(self, field_name)  # type: ignore[return-value]
        try:
            return self.values[self.spec.field_names.index(field_name)]
        except ValueError:
            raise KeyError(f"{self.name} has no field {field_name!r}") from None

    def __contains__(self, field_name: object) -> bool:
        return field_name in self.spec.field_names

    def as_dict(self) -> dict[str, Value]:
        return dict(zip(self.spec.field_names, self.values, strict=True))

    def same_as(self, other: Record) -> bool:
        """Equality that counts NaN equal to NaN (an Inertia-Link's magnetometer)."""
        return self.spec is other.spec and _flat(self.values) == _flat(other.values)


def _flat(values: object) -> tuple:
    if isinstance(values, tuple):
        return tuple(x for v in values for x in _flat(v))
    if isinstance(values, float) and math.isnan(values):
        return ("nan",)
    return (values,)


def decode(data: bytes | bytearray | memoryview, start: int = 0,
           stop: int | None = None) -> Record:
    """Decode reply bytes (echo byte first, no checksum) into a :class:`Record`: all of
    ``data``, or ``data[start:stop]`` read in place (a packet's record without a copy).

    Raises :class:`RecordError` for an unknown echo byte or a length that does not
    match the layout; a record is never decoded from the wrong number of bytes.
    """
    length = (len(data) if stop is None else min(stop, len(data))) - start
    if length <= 0:
        raise RecordError("an empty reply has no echo byte")
    spec = BY_CODE.get(data[start])
    if spec is None or spec.reply is None:
        raise RecordError(f"0x{data[start]:02X} is not a GX2 reply record")
    size = spec.reply_struct.size
    if length != size and not (spec.reply_may_run_long and length > size):
        raise RecordError(f"0x{spec.code:02X} {spec.name}: {length} bytes, "
                          f"its layout needs {size}")
    # one Record for every record: built without NamedTuple's Python-level __new__,
    # 1.5% fewer instructions a record on the daemon's read path (bench/instructions.py)
    return _new_tuple(Record, (spec, shape(spec, spec.reply_struct.unpack_from(data,
                                                                          start))))


_new_tuple = tuple.__new__


def shape(spec: CommandSpec, items: tuple) -> tuple[Value, ...]:
    """Group the flat struct items after the echo byte into the spec's field values."""
    # a flat layout (every streamed record but those holding a matrix) is grouped by
    # one itemgetter call: 2.3x faster than the loop below for accel_angrate, about
    # 0.5 us a record (bench/micro.py)
    getter = spec.reply_getter
    if getter is not None:
        return getter(items)
    values = []
    for start, stop, f in spec.reply_slices:
        kind = f.type.shape
        if kind in _AS_SLICE:
            values.append(items[start:stop])
        elif kind in _AS_ITEM:
            values.append(items[start])
        else:
            values.append(f.type.shape_items(items[start:stop]))
    return tuple(values)


def encode(record: str | int, **fields: object) -> bytes:
    """Build reply bytes (echo byte first, no checksum) from field values by name.

    The simulator builds every reply with this, so the simulator and the decoder share
    one definition of each record. Raises :class:`aspp.errors.CommandError` naming a
    missing, unknown or ill-shaped field.
    """
    spec = lookup(record)
    if spec.reply is None:
        raise CommandError(f"0x{spec.code:02X} {spec.name} has no reply to encode")
    unknown = set(fields) - set(spec.field_names)
    if unknown:
        raise CommandError(f"{spec.name} has no field {sorted(unknown)[0]!r}")
    items: list[object] = [spec.code]
    for f in spec.reply:
        if f.name not in fields:
            raise CommandError(f"{spec.name} needs a value for {f.name!r}")
        items.extend(f.type.flatten(f.name, fields[f.name]))
    return spec.reply_struct.pack(*items)


def markdown_table() -> str:
    """The record table as docs/interface.md shows it, generated so the two cannot disagree."""
    lines = ["| cmd | record | request after the command byte | reply fields after the echo "
             "| reply bytes |", "|---|---|---|---|---|"]
    for spec in _SPECS:
        request = " ".join(item.value.hex(" ").upper() if isinstance(item, Const)
                           else f"{item.name}:{item.type.name}" for item in spec.request)
        reply = ("(none)" if spec.reply is None else
                 ", ".join(f"{f.name}:{f.type.name}" for f in spec.reply))
        size = "-" if spec.reply_size is None else str(spec.reply_size)
        stream = " (streams)" if spec.streamable else ""
        lines.append(f"| 0x{spec.code:02X} | {spec.name}{stream} | {request or '-'} "
                     f"| {reply} | {size} |")
    return "\n".join(lines)
