"""A picture of one node's recorded stream: a panel per field group against time.

Vectors are one panel each (x, y, z), Euler angles one panel together, other scalars a
panel per unit; matrices and the timer are left out (a matrix's nine lines say less
than the Euler angles beside it). Time is seconds from the first sample (``time``, or
``device_time`` for records without it). Where samples are missing (a step longer
than GAP_FACTOR periods, or a ``seq`` gap) the lines break, so a loss shows as a gap.
Marks (``gx2ctl mark``) of the node or of the whole experiment, made within the
samples' time, are vertical lines labelled with their text (none against
``device_time``: a mark's time is UNIX time). matplotlib is an optional extra,
imported only here.
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aspp.records import BY_NAME
from gateway.common.topics import parse

from .export import MissingExtra
from .files import MARK, Mark, Reading, read_all

GAP_FACTOR = 1.5
INSTALL_PLOT = "pip install 'gx2-gateway[plot]'"
SKIPPED = frozenset(("timer",))
NAN = float("nan")
MARK_COLOUR = "tab:red"


@dataclass
class Series:
    """One panel: its title, unit, and lines (label -> values, aligned with ``x``)."""

    title: str
    unit: str
    lines: dict[str, list[float]] = field(default_factory=dict)


@dataclass
class Picture:
    """What is drawn: x (seconds), the panels, the title, and where x comes from."""

    x: list[float]
    panels: list[Series]
    title: str
    x_label: str
    marks: list[tuple[float, str]] = field(default_factory=list)
    """(x, text) of each mark drawn."""


@dataclass
class Found:
    """What a recording holds of one node's record."""

    record: str
    payloads: list[dict]
    name: str | None
    marks: list[Mark]


def records_of(paths: list[Path], node: int, record: str | None,
               reading: Reading) -> Found:
    """The node's records of one kind (by default the kind it has most of), its name,
    and the marks that concern it, from the recordings; ValueError if there is none."""
    counts: Counter[str] = Counter()
    payloads: dict[str, list[dict]] = {}
    marks: list[Mark] = []
    name = None
    for entry in read_all(paths, reading):
        if entry.topic == "gx2/gateway/status":
            for listed in entry.payload().get("nodes") or []:
                if isinstance(listed, dict) and listed.get("node") == node and listed.get(
                        "name"):
                    name = str(listed["name"])
            continue
        if entry.topic == MARK:
            mark = Mark.of(entry)
            if mark.concerns(node):
                marks.append(mark)
            continue
        where = parse(entry.topic)
        if where is None or where[0] != node or (record and where[1] != record):
            continue
        counts[where[1]] += 1
        payloads.setdefault(where[1], []).append(entry.payload())
    if not counts:
        what = f"record {record} of node {node}" if record else f"records of node {node}"
        raise ValueError(f"no {what} in {', '.join(map(str, paths))}")
    chosen = record or counts.most_common(1)[0][0]
    return Found(chosen, payloads[chosen], name, marks)


def picture(node: int, record: str, payloads: list[dict], name: str | None,
            marks: list[Mark] | None = None) -> Picture:
    """The panels, title and marks for ``payloads`` (one node's records of one kind)."""
    clock = "time" if any(isinstance(p.get("time"), (int, float)) for p in payloads) \
        else "device_time"
    rows = [p for p in payloads if isinstance(p.get(clock), (int, float))]
    if not rows:
        raise ValueError(f"node {node}'s {record} records carry no time to plot against")
    start = rows[0][clock]
    x = [p[clock] - start for p in rows]
    steps = [b - a for a, b in itertools.pairwise(x) if b > a]
    period = statistics.median(steps) if steps else 0.0
    seqs = [p.get("seq") for p in rows]
    breaks = [i for i in range(1, len(rows)) if (period and x[i] - x[i - 1] > GAP_FACTOR
                                                 * period) or _seq_gap(seqs[i - 1], seqs[i])]
    lost = sum(seqs[i] - seqs[i - 1] - 1 for i in range(1, len(seqs))
               if _seq_gap(seqs[i - 1], seqs[i]))
    panels = _panels(record, rows)
    x_out = _with_breaks(x, breaks)
    for panel in panels:
        for label, values in panel.lines.items():
            panel.lines[label] = _with_breaks(values, breaks)
    who = f"{name} ({node})" if name else f"node {node}"
    rate = f"{1 / period:.1f} Hz" if period else "rate unknown"
    expected = len(rows) + lost
    share = f" ({100 * lost / expected:.2f}%)" if expected else ""
    title = f"{who}: {record}, {rate}, {lost} lost{share}, {len(rows)} records"
    when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(start)) if clock == "time" \
        else "the node's timer"
    shown = [(mark.time - start, mark.text) for mark in marks or ()
             if clock == "time" and x[0] <= mark.time - start <= x[-1]]
    return Picture(x_out, panels, title, f"seconds from {when} ({clock})", shown)


def _seq_gap(before: Any, after: Any) -> bool:
    return isinstance(before, int) and isinstance(after, int) and after > before + 1


def _with_breaks(values: list[float], breaks: list[int]) -> list[float]:
    """``values`` with a NaN before each index in ``breaks``: matplotlib breaks a line
    at a NaN."""
    out: list[float] = []
    marks = set(breaks)
    for i, value in enumerate(values):
        if i in marks:
            out.append(NAN)
        out.append(value)
    return out


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(
        value, bool) else NAN


def _panels(record: str, rows: list[dict]) -> list[Series]:
    spec = BY_NAME.get(record)
    layout = ([(f.name, f.type.shape, f.doc) for f in spec.reply] if spec else
              [(k, "vector" if isinstance(v, list) else "float", "")
               for k, v in rows[0].items() if isinstance(v, (int, float, list))])
    panels: list[Series] = []
    by_unit: dict[str, Series] = {}
    for name, shape, units in layout:
        if name in SKIPPED or shape in ("matrix", "text") or name in ("seq", "lqi", "rssi",
                                                                      "node", "command"):
            continue
        unit = units.split(";")[0].strip() if units else ""
        if shape in ("vector", "ints"):
            values = [p.get(name) if isinstance(p.get(name), list) else [] for p in rows]
            size = max((len(v) for v in values), default=0)
            labels = ("x", "y", "z") if size == 3 else tuple(str(i + 1) for i in range(size))
            panel = Series(name.replace("_", " "), unit)
            for i, label in enumerate(labels):
                panel.lines[label] = [_number(v[i]) if i < len(v) else NAN for v in values]
            panels.append(panel)
            continue
        key = unit or name
        panel = by_unit.get(key)
        if panel is None:
            title = "Euler angles" if name in ("roll", "pitch", "yaw") else name.replace("_", " ")
            panel = by_unit[key] = Series(title, unit)
            panels.append(panel)
        panel.lines[name] = [_number(p.get(name)) for p in rows]
    return [p for p in panels if any(not math.isnan(v) for vs in p.lines.values()
                                     for v in vs)]


def draw(image: Picture, out: Path) -> None:
    """Render ``image`` to a PNG at ``out``."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        from matplotlib import pyplot
    except ImportError:
        raise MissingExtra(f"plotting needs matplotlib: {INSTALL_PLOT}") from None
    count = max(len(image.panels), 1)
    figure, axes = pyplot.subplots(count, 1, sharex=True, squeeze=False,
                                   figsize=(11, 2.4 * count + 1.2))
    for axis, panel in zip(axes[:, 0], image.panels, strict=False):
        for label, values in panel.lines.items():
            axis.plot(image.x, values, linewidth=0.8, label=label)
        axis.set_ylabel(f"{panel.title}\n({panel.unit})" if panel.unit else panel.title)
        axis.grid(True, alpha=0.3)
        axis.legend(loc="upper right", fontsize="small", ncol=len(panel.lines))
        for at, _ in image.marks:
            axis.axvline(at, color=MARK_COLOUR, linewidth=1.0, linestyle="--")
    for at, text in image.marks:
        # the label once, at the top panel's top edge (x in data, y in the axes' own
        # 0..1), so it stays put whatever the panel's values
        axes[0, 0].annotate(text, (at, 1.0), xycoords=("data", "axes fraction"),
                            xytext=(2, -2), textcoords="offset points", rotation=90,
                            va="top", ha="left", fontsize="small", color=MARK_COLOUR)
    axes[-1, 0].set_xlabel(image.x_label)
    figure.suptitle(image.title)
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    pyplot.close(figure)
