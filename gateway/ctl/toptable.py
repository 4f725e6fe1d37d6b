"""The node table of ``gx2ctl top``: a row per node, its columns cut or dropped to fit
the terminal's width (never wrapped), each cell a pure function of the node's status
and the time, so the layout is tested without a terminal."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from rich.cells import cell_len
from rich.text import Text

from gateway.common.protocol import HealthLevel
from gateway.common.reading import as_map, number

from .cells import MISSING, cell, clock_cell
from .columns import GAP, Column, fit, sized

HEALTH_STYLE = {HealthLevel.OK: "green", HealthLevel.WARN: "bold yellow",
                HealthLevel.ERROR: "bold red"}


def _hz(node: Mapping[str, Any], now: float) -> str:
    rate, expected = number(node.get("rate_hz")), number(node.get("expected_hz"))
    shown = MISSING if rate is None else f"{rate:.1f}"
    return f"{shown}/{expected:.4g}" if expected else shown


def _lost(node: Mapping[str, Any], now: float) -> str:
    """Lost over the radio in the recent window: the count and its share."""
    recent = as_map(node.get("recent"))
    count, share = number(recent.get("lost_radio")), number(recent.get("lost_radio_percent"))
    if count is None:
        return MISSING
    return f"{count:.0f} {share:.1f}%" if share is not None else f"{count:.0f}"


def _seen(node: Mapping[str, Any], now: float) -> str:
    seen = number(node.get("last_seen"))
    if seen is None:
        return "never" if node.get("last_seen") is None else MISSING
    return age_text(now - seen)


def age_text(age: float) -> str:
    """How long ago, in at most five cells: ``0.3s``, ``42s``, ``12m``, ``5h``, ``3d``."""
    age = max(0.0, age)
    for unit, seconds in (("d", 86400), ("h", 3600), ("m", 60)):
        if age >= 2 * seconds:
            return f"{age / seconds:.0f}{unit}"
    return f"{age:.1f}s" if age < 10 else f"{age:.0f}s"


def _clock(node: Mapping[str, Any], now: float) -> str:
    return clock_cell(node.get("clock"), unit="")


def _name(node: Mapping[str, Any], now: float) -> str:
    name = node.get("name")
    return f"{cell(node.get('node'))} {cell(name)}" if name else cell(node.get("node"))


def _key(key: str) -> Callable[[Mapping[str, Any], float], str]:
    return lambda node, now: cell(node.get(key))


COLUMNS = (
    Column("node", _name),
    Column("state", _key("state")),
    Column("record", _key("record")),
    Column("Hz", _hz, right=True),
    Column("lost", _lost, right=True),
    Column("gw", _key("lost_gateway"), right=True),
    Column("boots", _key("reboots"), right=True),
    Column("LQI", _key("lqi"), right=True),
    Column("RSSI", _key("rssi"), right=True),
    Column("clock", _clock, right=True),
    Column("seen", _seen, right=True),
    Column("health", _key("health")),
)
GIVE_WAY: tuple[tuple[str, int], ...] = (
    ("record", 10), ("LQI", 0), ("gw", 0), ("boots", 0), ("node", 10), ("clock", 0),
    ("node", 7), ("record", 7), ("seen", 0), ("lost", 0), ("RSSI", 0), ("Hz", 0),
    ("record", 0), ("state", 0),
)
"""What gives way, in turn, while the table is wider than the terminal: a column cut to
so many cells (with an ellipsis), or dropped (0). The node and its health stay."""
HEALTH = next(i for i, column in enumerate(COLUMNS) if column.header == "health")


def cut(line: Text, width: int, ellipsis: str = "…") -> Text:
    """``line`` cut to ``width`` cells, its last one an ellipsis if anything was cut."""
    if cell_len(line.plain) > width:
        line.truncate(max(0, width - 1), overflow="crop")
        line.append(ellipsis[:width])
    return line


def table(nodes: Sequence[Mapping[str, Any]], now: float, width: int,
          ellipsis: str = "…", stale_for: float | None = None,
          each: Sequence[tuple[float, float | None]] | None = None) -> list[Text]:
    """The header and a row per node, each line at most ``width`` cells. ``stale_for``:
    seconds since the status they come from, given once a heartbeat was missed; each
    row is then grey, its health unknown (``stale 2.1s``), never a green OK that
    nothing vouches for any more. ``each``: per node, its own (now, stale_for), for
    nodes of several gateways in one table."""
    each = each if each is not None else [(now, stale_for)] * len(nodes)
    cells = [[column.cell(node, at) for column in COLUMNS]
             for node, (at, _) in zip(nodes, each, strict=True)]
    for row, (_, stale) in zip(cells, each, strict=True):
        if stale is not None:
            row[HEALTH] = f"stale {age_text(stale)}"
    shown = fit(COLUMNS, cells, width, GIVE_WAY)
    header = Text(" " * GAP).join(Text(sized(COLUMNS[i].header, w, COLUMNS[i].right))
                                  for i, w in shown)
    header.stylize("bold")
    lines = [header]
    for node, row, (_, stale) in zip(nodes, cells, each, strict=True):
        parts = []
        for i, w in shown:
            text = Text(sized(row[i], w, COLUMNS[i].right, ellipsis))
            if i == HEALTH and stale is None:
                text.stylize(HEALTH_STYLE.get(str(node.get("health")), ""))
            parts.append(text)
        row_text = Text(" " * GAP).join(parts)
        row_text.rstrip()
        if stale is not None:
            row_text.stylize("dim")
        lines.append(row_text)
    return lines
