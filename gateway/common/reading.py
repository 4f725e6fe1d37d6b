"""Reading maps another process sent (a status, a reply): of another version perhaps,
so a value is taken only when it has the type expected, and otherwise left out, never
guessed and never a crash."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any


def number(value: Any) -> float | None:
    """A finite real number, or None (a bool, a string, NaN, an infinity or an integer
    too large for a float, such as a foreign recording's 10**400, is not one)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        real = float(value)
    except OverflowError:
        return None
    return real if math.isfinite(real) else None


def as_map(value: Any) -> Mapping[str, Any]:
    """``value`` if it is a map, else an empty one."""
    return value if isinstance(value, Mapping) else {}
