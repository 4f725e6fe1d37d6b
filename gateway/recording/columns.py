"""What an exported table's columns hold: a type a typed format (Parquet, .mat) can keep,
and each column's meaning and unit, taken from the recordings' JSON Schemas
(:mod:`gateway.common.schemas`), so a unit is written down once, in the record table.

Kinds: ``time`` (UNIX seconds in the messages, a UTC timestamp in Parquet),
``duration`` (seconds of a node's timer), ``float``, ``text``, and integers by their
width (``uint8`` .. ``int64``), the smallest that holds every value the field can take.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal
from typing import Any

from aspp.records import BY_NAME, derived
from gateway.common.schemas import Notes, mark_notes, record_notes

UNSIGNED = (("uint8", 0xFF), ("uint16", 0xFFFF), ("uint32", 0xFFFF_FFFF))
LOST_BEFORE = ("samples of the node's stream missing just before this row, by its "
               "timer's steps; null where not known", "samples")
"""export's own column (not a published field): its meaning is said here, once."""
PLACED = ("how time was placed when refined after the fact: between (sightings of "
          "the node's floor on both sides), one_side, live (as recorded), unplaceable "
          "(no packet of its power-up showed the floor)", "")
BOUND_MS = ("how far time may be from the sample instant, as refined (the floor's "
            "noise and the drift's bend across the sightings around it); null where none "
            "is known (live, unplaceable)", "ms")
"""The columns of a refined export (:mod:`.refined`), said here, once."""
NODES_TEXT = "the addresses it concerns, space-separated; empty: the whole experiment"
"""A mark's ``nodes`` as a table holds them: one text, not a list."""


@dataclass(frozen=True)
class Column:
    """One column of an exported table."""

    name: str
    kind: str
    meaning: str = ""
    unit: str = ""


_LEADING_KINDS = {"time": "time", "host_time": "time", "device_time": "duration",
                  "seq": "int64", "lost_before": "int64", "lqi": "uint8", "rssi": "int8",
                  "time_placed": "text", "time_bound_ms": "float"}


def record_columns(record: str, leading: Sequence[str],
                   fields: Sequence[tuple[str, str, int]],
                   first: dict[str, Any]) -> list[Column]:
    """The columns of ``record``'s table: ``leading`` (the bookkeeping every row has),
    then ``fields`` ((column, field, index), as export lays them out). A field of a
    record this version does not know is typed by its value in the ``first`` row: text
    for a string, else float (JSON does not tell 1 from 1.0)."""
    notes = record_notes(record)
    notes["lost_before"] = LOST_BEFORE
    notes["time_placed"], notes["time_bound_ms"] = PLACED, BOUND_MS
    spec = BY_NAME.get(record)
    types = ({f.name: f.type for f in (*spec.reply, *derived(spec))}
             if spec is not None and spec.reply else {})
    columns = [_noted(name, _LEADING_KINDS[name], notes, name) for name in leading]
    for column, field, _ in fields:
        kind = types.get(field)
        if kind is None:
            text = isinstance(first.get(field), str)
            columns.append(_noted(column, "text" if text else "float", notes, field))
        elif kind.shape in ("int", "ints"):
            columns.append(_noted(column, _unsigned(kind.max_int), notes, field))
        elif kind.shape == "text":
            columns.append(_noted(column, "text", notes, field))
        else:
            columns.append(_noted(column, "float", notes, field))
    return columns


def mark_columns() -> list[Column]:
    """The marks' table: ``time``, ``host_time``, ``nodes``, ``text``."""
    notes = mark_notes()
    return [_noted("time", "time", notes, "time"), _noted("host_time", "time", notes,
                                                          "host_time"),
            Column("nodes", "text", NODES_TEXT), _noted("text", "text", notes, "text")]


def _noted(name: str, kind: str, notes: Notes, field: str) -> Column:
    meaning, unit = notes.get(field, ("", ""))
    return Column(name, kind, meaning, unit)


def _unsigned(largest: int) -> str:
    return next((kind for kind, top in UNSIGNED if largest <= top), "int64")


def nanoseconds(seconds: Any) -> int | None:
    """Seconds as whole nanoseconds; None for what is not a finite number. The
    decimal the message's JSON wrote (the float's shortest form, as Python reads and
    writes it) is taken exactly: ``round(seconds * 1e9)`` would be off by up to 128 ns
    for a UNIX time, a product of that size being a double's multiple of 256."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
        return None
    if isinstance(seconds, int):
        return seconds * 1_000_000_000
    if seconds != seconds or seconds in (float("inf"), float("-inf")):
        return None
    return int(Decimal(repr(seconds)).scaleb(9).to_integral_value(ROUND_HALF_EVEN))
