"""Times shown to a person, by one function: an instant reads the same wherever it is
shown (``gx2ctl mark``, ``recordings``, export's and plot's lines, a window's errors,
top's clock). UTC, as recordings are named and windows are given, and rounded to the
digits shown, never cut: a mark made at 06:21:40.6955 was ``06:21:40.695`` in what
``mark`` printed and ``06:21:40.696`` in ``recordings`` (issue 43)."""

from __future__ import annotations

import time
from typing import Any

from .reading import number

DAY = "%Y-%m-%d %H:%M:%S"
"""The date and the time of day: ``2026-11-25 10:20:00.000``."""
TIME = "%H:%M:%S"
"""The time of day alone: ``10:20:00.000``."""
ISO = "%Y-%m-%dT%H:%M:%S"
"""ISO 8601, as ``--from`` takes it back (with ``zone="Z"``)."""
UTC = " UTC"


def at(stamp: int, shape: str = DAY, digits: int = 3, zone: str = UTC) -> str:
    """``stamp`` (UNIX ns) in UTC as ``shape`` (a strftime format), rounded to
    ``digits`` decimals of the second, then ``zone``."""
    unit = 10 ** (9 - digits)
    whole, part = divmod((stamp + unit // 2) // unit, 10 ** digits)
    text = time.strftime(shape, time.gmtime(whole))
    return (f"{text}.{part:0{digits}d}" if digits else text) + zone


def nanoseconds(seconds: float) -> int:
    """UNIX seconds as the nanoseconds a recording holds them in (its log_time:
    ``gateway.recording.files.ns`` rounds as this does), so a time a reply gave and the
    same time read from a recording show alike."""
    return round(seconds * 1e9)


def seconds_at(value: Any, shape: str = DAY, digits: int = 3, zone: str = UTC
               ) -> str | None:
    """A UNIX time in seconds, from another process's map (a reply, a status), as
    :func:`at` shows it; None for anything that is not such a time."""
    seconds = number(value)
    if seconds is None:
        return None
    try:
        return at(nanoseconds(seconds), shape, digits, zone)
    except (OverflowError, OSError, ValueError):
        return None
