"""A table that fits a terminal's width: what ``gx2ctl status`` and ``top`` print.

Each column is as wide as its widest cell; while the table is wider than the terminal,
columns give way in a stated order (each table states its own: what matters least to
its reader first), cut to so many cells with an ellipsis, or dropped. Nothing wraps: a
wrapped row of numbers is read as the row below. Widths are terminal cells (rich's
``cell_len``), so a name in CJK or with emoji lines up too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rich.cells import cell_len, set_cell_size

GAP = 1
"""Spaces between columns."""
ELLIPSIS = "…"

GiveWay = Sequence[tuple[str, int]]
"""Steps taken in turn while a table is too wide: (a column's header, cells), the
column cut to so many cells, or dropped (0)."""


@dataclass(frozen=True)
class Column:
    header: str
    cell: Callable[[Mapping[str, Any], float], str]
    """The cell of a node's map, at ``now`` (UNIX time)."""
    right: bool = False


def fit(columns: Sequence[Column], rows: Sequence[Sequence[str]], width: int | None,
        give_way: GiveWay, gap: int = GAP) -> list[tuple[int, int]]:
    """The columns shown within ``width`` cells (None: all, whole), as (index, cells):
    each as wide as its widest cell, then the steps of ``give_way`` taken in turn until
    the table fits. The room left after the last step brings back what was dropped,
    last dropped first, where it fits whole; what remains goes back to the columns
    that were cut."""
    wanted = [max([cell_len(c.header), *(cell_len(row[i]) for row in rows)])
              for i, c in enumerate(columns)]
    widths = dict(enumerate(wanted))
    if width is None:
        return sorted(widths.items())
    index = {column.header: i for i, column in enumerate(columns)}
    dropped: list[int] = []

    def room() -> int:
        return width - sum(widths.values()) - gap * (len(widths) - 1)

    for header, cells in give_way:
        if room() >= 0:
            break
        i = index[header]
        if i in widths:
            if cells:
                widths[i] = min(widths[i], cells)
            else:
                del widths[i]
                dropped.append(i)
    for i in reversed(dropped):
        if wanted[i] + gap <= room():
            widths[i] = wanted[i]
    for i in sorted(widths):
        widths[i] += min(wanted[i] - widths[i], max(0, room()))
    return sorted(widths.items())


def sized(text: str, width: int, right: bool = False, ellipsis: str = ELLIPSIS) -> str:
    """``text`` in exactly ``width`` terminal cells: padded, or cut with an ellipsis."""
    if cell_len(text) > width:
        text = (set_cell_size(text, width - 1).rstrip() + ellipsis if width > 1
                else set_cell_size(text, width))
    pad = " " * (width - cell_len(text))
    return pad + text if right else text + pad


def clipped(text: str, width: int | None, ellipsis: str = ELLIPSIS) -> str:
    """A line of text within ``width`` cells (None: as it is), cut with an ellipsis."""
    if width is None or cell_len(text) <= width:
        return text
    return set_cell_size(text, max(0, width - 1)).rstrip() + ellipsis[:width]


def plain_table(columns: Sequence[Column], rows: Sequence[Sequence[str]],
                shown: Sequence[tuple[int, int]], ellipsis: str = ELLIPSIS) -> list[str]:
    """The header and the rows as lines of text, in the columns ``fit`` chose."""
    def line(cells: Sequence[str]) -> str:
        return (" " * GAP).join(sized(cells[i], w, columns[i].right, ellipsis)
                                for i, w in shown).rstrip()
    return [line([c.header for c in columns]), *(line(row) for row in rows)]
