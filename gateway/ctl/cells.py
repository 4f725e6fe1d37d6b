"""The cells gx2ctl prints of a gateway's reply, readable whatever the reply holds.

The gateway's results are data from another process (another version, perhaps): each
function here tolerates missing keys, extra keys and unexpected types, giving ``-``
rather than failing, so a newer or older gateway never makes gx2ctl crash.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from gateway.common.reading import number

MISSING = "-"


def cell(value: Any) -> str:
    """One table cell or inline value, readable whatever its type."""
    if value is None:
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:g}" if math.isfinite(value) else MISSING
    text = str(value)
    return " ".join(text.split()) or MISSING


def duration(seconds: Any) -> str:
    """``12.3 s``, ``4 min 05 s``, ``2 h 03 min``, ``3 d 04 h``."""
    value = number(seconds)
    if value is None:
        return MISSING
    if value < 60:
        return f"{max(value, 0.0):.1f} s"
    whole = int(value)
    days, rest = divmod(whole, 86400)
    hours, rest = divmod(rest, 3600)
    minutes, secs = divmod(rest, 60)
    if days:
        return f"{days} d {hours:02d} h"
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {secs:02d} s"


def ago(timestamp: Any, now: float) -> str:
    """How long before ``now`` a UNIX time was; ``never`` for None."""
    if timestamp is None:
        return "never"
    value = number(timestamp)
    return MISSING if value is None else f"{duration(now - value)} ago"


def count(value: Any, unit: str) -> str:
    text = cell(value)
    return f"{text} {unit}" if text != MISSING else MISSING


def clock_cell(clock: Any, unit: str = " ppm") -> str:
    """A node's clock estimate in a few characters: its drift and whether it is locked
    ("+40.1 ppm" locked, "~+40.1 ppm" still settling, "-" before a timed record), and,
    while its floor has gone unseen past the gateway's threshold, how late ``time`` may
    be ("+40.1 ppm, <=1.4 ms late": status's ``late_ms``), or that it has never seen
    its floor ("+40.1 ppm, floor unseen")."""
    if not isinstance(clock, Mapping):
        return "-"
    drift = number(clock.get("drift_ppm"))
    shown = "?" if drift is None else f"{drift:+.1f}{unit}"
    late = number(clock.get("late_ms"))
    if late is not None:
        shown += f", <={late:.1f} ms late"
    elif clock.get("floor_seen") is False and clock.get("locked") is True:
        shown += ", floor unseen"  # (late by a wait no packet shows: no bound to give)
    return shown if clock.get("locked") is True else f"~{shown}"


def node_maps(result: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    nodes = result.get("nodes")
    return [node for node in (nodes if isinstance(nodes, list) else [])
            if isinstance(node, Mapping)]


def reasons(node: Mapping[str, Any]) -> str:
    """Why a node (or the gateway itself) is not OK, in one line ("" if it is, or if
    the gateway gave none)."""
    given = node.get("reasons")
    return "; ".join(cell(r) for r in given) if isinstance(given, list) else ""
