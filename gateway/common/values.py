"""The kinds of value a command line or a control request carries: a node address, a
record, an EEPROM word, a data rate, ... Each kind reads itself from command-line text
and checks a value that came over the wire, with one message for both, so gx2ctl
refuses a bad argument (exit 2) with the very words the gateway would answer it with.

A check raises ValueError with a message that does not name the field: the caller
knows which field it is (argparse names the argument, pydantic the key).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from aspp.errors import AsppError
from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import STREAMABLE, all_specs, checked
from aspp.timing import divider_for_rate

from .topics import STATION_NAME


@dataclass(frozen=True)
class Kind:
    """One kind of value. ``type`` is what it is on the wire (msgpack gives ints,
    floats, strings); ``read`` turns command-line text into such a value and ``check``
    validates one, returning it in the form the gateway uses. ``choices``, for a kind
    with few values, lists them (gx2ctl's help shows them)."""

    name: str
    type: Any
    read: Callable[[str], Any]
    check: Callable[[Any], Any]
    choices: tuple[str, ...] = ()

    def from_text(self, text: str) -> Any:
        return self.check(self.read(text))


def integer(text: str) -> int:
    """Decimal or 0x hexadecimal, nothing else (``076`` is 76, not octal)."""
    body = text.strip()
    if body.isascii():
        if body[:2].lower() == "0x" and body[2:].isalnum():
            try:
                return int(body[2:], 16)
            except ValueError:
                pass
        elif body.isdecimal():
            return int(body, 10)
    raise ValueError(f"{text!r} is not a decimal or 0x hexadecimal number")


def number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not a finite number")
    return value


def in_range(low: int, high: int, what: str) -> Callable[[int], int]:
    def check(value: int) -> int:
        if not low <= value <= high:
            raise ValueError(f"{what} {value} is out of range {low}..{high}")
        return value
    return check


def _node(text: str) -> int:
    try:
        return integer(text)
    except ValueError:
        raise ValueError(f"node address {text!r} is not a number") from None


def _addresses(text: Any) -> tuple[int, ...]:
    """``1-100,200,300-310`` -> every address it names, ascending, each once."""
    if not isinstance(text, str):
        raise ValueError(f"address ranges are text such as 1-100,200, not {text!r}")
    if not text.strip():
        raise ValueError("no addresses given (such as 1-100,200,300-310)")
    addresses: set[int] = set()
    for part in text.split(","):
        first, dash, last = (side.strip() for side in part.partition("-"))
        if not first or (dash and not last):
            within = f" in {text!r}" if part.strip() != text.strip() else ""
            raise ValueError(f"{part.strip()!r}{within} is not an address or a range of "
                             "them (such as 1-100,200,300-310)")
        low = NODE.from_text(first)
        high = NODE.from_text(last) if dash else low
        if high < low:
            raise ValueError(f"range {part.strip()!r} runs backwards")
        addresses.update(range(low, high + 1))
    return tuple(sorted(addresses))


def ranges_text(addresses: Any) -> str:
    """The addresses as the ranges :data:`ADDRESS_RANGES` reads: [1, 2, 3, 7] -> ``1-3,7``."""
    parts: list[str] = []
    run: list[int] = []
    for address in sorted(set(addresses)):
        if run and address != run[-1] + 1:
            parts.append(_run_text(run))
            run = []
        run.append(address)
    if run:
        parts.append(_run_text(run))
    return ",".join(parts)


def _run_text(run: list[int]) -> str:
    return str(run[0]) if len(run) == 1 else f"{run[0]}-{run[-1]}"


def _station(value: Any) -> str:
    if not isinstance(value, str) or not re.match(STATION_NAME, value):
        raise ValueError(f"{value!r} is not a base station's name (letters, digits, _ and "
                         "-, at most 32)")
    return value


def _record(streamable: bool = False, pollable: bool = False) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        try:
            return checked(value, streamable=streamable, pollable=pollable).name
        except AsppError as error:
            raise ValueError(str(error)) from None
    return check


def _rate(hz: float) -> float:
    try:
        divider_for_rate(hz)
    except AsppError as error:
        raise ValueError(str(error)) from None
    return float(hz)


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{value} is not a finite number")
    return float(value)


def _one_of(choices: tuple[str, ...], what: str) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        if value not in choices:
            raise ValueError(f"{what} {value!r} is not one of {', '.join(choices)}")
        return value  # type: ignore[no-any-return]
    return check


def _names(streamable: bool = False, pollable: bool = False) -> tuple[str, ...]:
    return tuple(spec.name for spec in all_specs()
                 if (not streamable or spec.code in STREAMABLE)
                 and (not pollable or spec.pollable))


NODE = Kind("node address", int, _node, in_range(MIN_NODE, MAX_NODE, "node address"))
STREAMABLE_RECORD = Kind("record that can stream", str | int, str,
                         _record(streamable=True), _names(streamable=True))
POLLABLE_RECORD = Kind("record that can be polled", str | int, str, _record(pollable=True),
                       _names(pollable=True))
ADDRESS_RANGES = Kind("node address ranges", str, str, _addresses)
"""Node addresses as ranges (``1-100,200,300-310``), read into every address they name;
each one a node address (1..65534)."""
STATION = Kind("base station name", str, str, _station)
WORD = Kind("16-bit word", int, integer, in_range(0, 0xFFFF, "word"))
"""An EEPROM address or value."""
RATE_HZ = Kind("data rate in Hz", float, number, _rate)
FLOAT = Kind("number", float, number, _finite)
SAMPLING_MS = Kind("sampling time in ms", int, integer, in_range(1, 0xFFFF, "sampling time"))
SENSORS = ("accel", "gyro")
SENSOR = Kind("sensor", str, str, _one_of(SENSORS, "sensor"), SENSORS)
