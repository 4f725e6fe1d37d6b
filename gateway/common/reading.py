"""Reading maps another process sent (a status, a reply): of another version perhaps,
so a value is taken only when it has the type expected, and otherwise left out, never
guessed and never a crash."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any


def number(value: Any) -> float | None:
    """A finite real number, or None (a bool, a string, NaN or an infinity is not one)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def as_map(value: Any) -> Mapping[str, Any]:
    """``value`` if it is a map, else an empty one."""
    return value if isinstance(value, Mapping) else {}
