"""One message of a recording, as the readers that take messages one at a time (replay,
plot, the client, a refined export) take it, and its JSON parsed as the standard
library parses it. The export of tables takes a chunk's messages at once instead
(:mod:`.blocks`)."""

from __future__ import annotations

import json
from typing import Any, NamedTuple

import orjson

from .files import RecordingError


class Entry(NamedTuple):
    """One message of a recording (a named tuple: made 3x faster than a frozen
    dataclass, for every message read; bench/exportformats.py)."""

    topic: str
    log_time: int
    publish_time: int
    data: bytes
    after_damage: bool = False
    """A stretch of the file was skipped unread just before it (and after the message
    before it): what the streams miss across it was recorded, then lost by the file."""

    def payload(self) -> dict[str, Any]:
        """A JSON channel's message; RecordingError if it is not a JSON object."""
        try:
            value = _parsed(self.data)
        except ValueError:
            raise RecordingError(f"a message on {self.topic} is not JSON") from None
        if not isinstance(value, dict):
            raise RecordingError(f"a message on {self.topic} is not a JSON object")
        return value


def _parsed(data: bytes) -> Any:
    """The JSON in ``data``, as the standard library reads it. orjson: the refined
    export of 10 minutes of a saturated station (178,000 rows, each message read twice)
    in 0.91x the time the standard library's alone took (bench/commands.py,
    docs/performance-history.md); what orjson refuses (NaN, the infinities: another
    writer's) or would read otherwise (an integer past 64 bits, as a float) goes to the
    standard library, as it always did. ValueError if neither reads it."""
    try:
        value = orjson.loads(data)
    except ValueError:
        return json.loads(data)
    return json.loads(data) if _may_hold_a_long_integer(data) else value


_DIGITS = bytes.maketrans(b"0123456789", b"0" * 10)
_LONG = b"0" * 19


def _may_hold_a_long_integer(data: bytes) -> bool:
    """Whether ``data`` may hold an integer orjson reads otherwise than the standard
    library: past 64 bits (it keeps -2**63 to 2**64 - 1 as ints) it gives a float,
    without refusing it. Such an integer has 19 digits or more in a row, which the
    bytes show with every digit made one (a run of 19 in other numbers, a long
    fraction, only sends the message to the standard library, which reads it the
    same). 0.53 us a message of the demo's recording, against 2.2 us for the walk of
    orjson's values it replaced and 2.9 us for a regular expression (bench/jsonlong.py)."""
    return _LONG in data.translate(_DIGITS)


