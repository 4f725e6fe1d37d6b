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
    return json.loads(data) if _holds_a_long_integer(value) else value


def _holds_a_long_integer(value: Any) -> bool:
    """Whether orjson's reading may hold an integer past 64 bits: it reads one as a
    float (it keeps -2**63 to 2**64 - 1 as ints), without refusing it, so any float
    that far from 0 sends the message to the standard library (a float, to the same
    value; an integer, as it was). A walk of the values, not a search of the bytes:
    a regular expression for 20 digits took twice orjson's time and more."""
    items = [value]
    while items:
        item = items.pop()
        if isinstance(item, float):
            if not -(2.0**63) < item < 2.0**63:
                return True
        elif isinstance(item, dict):
            items.extend(item.values())
        elif isinstance(item, list):
            items.extend(item)
    return False


