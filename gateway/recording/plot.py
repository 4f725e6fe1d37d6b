"""A picture of one node's recorded stream: a panel per field group against time.

Every record gets a picture of what it holds: vectors are one panel each (x, y, z);
Euler angles one panel together, in degrees; an orientation matrix is drawn as the
Euler angles it makes (:func:`aspp.orientation.euler_from_matrix`), in degrees, and an
orientation update matrix as the angles of each cycle's turn; a list of integers (the
temperature codes) one panel; other scalars a panel per unit; the timer is left out. A
record with nothing to draw (a magnetometer an Inertia-Link lacks: all NaN) is said to
be so (ValueError), rather than drawn as empty panels. Time is seconds from the first
sample (``time``, or ``device_time`` for records without it).

Where samples are missing (:mod:`.losses`: a step of the timer longer than the stream's
period, a restart, or a step longer than GAP_FACTOR periods) every line breaks, so a
loss shows as a gap; where an angle wraps (a jump of more than HALF_TURN, from +180 to
-180 degrees) that line breaks, rather than being drawn across the panel. The title
gives the rate, and the samples lost by the radio (the timer's steps) and by the
gateway (``seq``) apart, as counts and shares, and those missed while the node's base
station was down (the recorded status messages) apart again. Each panel's legend is beside it, off
the data. Marks (``gx2ctl mark``) of the node or of the whole experiment, made within
the samples' time (or within the window read: a trial's closing mark comes after its
last sample), are vertical lines labelled with their text, inside the top panel
(shortened with an ellipsis where it is too long for it), none against
``device_time`` (a mark's time is UNIX time). How it is drawn, to a PNG or a PDF:
:mod:`.figure`.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aspp.orientation import euler_from_matrix
from aspp.records import BY_NAME
from gateway.common import timetext
from gateway.common.topics import parse

from .files import MARK, STATUS
from .losses import Counted, Losses, Stream
from .marks import Mark
from .reader import Entry, read_all
from .reports import Reading
from .summary import Summary
from .tables import BOUND, PLACED

if TYPE_CHECKING:
    from .refined import Refinement

GAP_FACTOR = 1.5
HALF_TURN = 180.0
"""Degrees an angle may step between two samples before the step is taken for a wrap."""
SKIPPED = frozenset(("timer", "seq", "lqi", "rssi", "node", "command", "lost_before", "time",
                     "host_time", "device_time", PLACED, BOUND))
EULER = ("roll", "pitch", "yaw")
NAN = float("nan")


@dataclass
class Series:
    """One panel: its title, unit, and lines (label -> values, aligned with ``x``);
    ``wraps``: its lines are angles in degrees, broken where they wrap."""

    title: str
    unit: str
    lines: dict[str, list[float]] = field(default_factory=dict)
    wraps: bool = False


@dataclass
class Picture:
    """What is drawn: x (seconds), the panels, the title, and where x comes from."""

    x: list[float]
    panels: list[Series]
    title: str
    x_label: str
    marks: list[tuple[float, str]] = field(default_factory=list)
    """(x, text) of each mark drawn."""
    losses: Summary = field(default_factory=Summary)
    """The samples of the stream received, lost by the radio and by the gateway, and
    missed while its base station was down."""


@dataclass
class Counts:
    """What is missing before each of a stream's payloads (:mod:`.losses`), in order,
    and the stream's period (seconds; None: not a stream)."""

    rows: list[Counted[int]]
    period: float | None


@dataclass
class Found:
    """What a recording holds of one node's record."""

    record: str
    payloads: list[dict]
    name: str | None
    marks: list[Mark]
    counts: Counts | None = None
    """Its losses, counted among all of the node's messages (its other records' ``seq``
    and continuous-mode replies included)."""


def records_of(paths: list[Path], node: int, record: str | None,
               reading: Reading, entries: Iterable[Entry] | None = None,
               refined: Refinement | None = None) -> Found:
    """The node's records of one kind (by default the kind it has most of), its name,
    and the marks that concern it, from the recordings (or from ``entries``, a window
    of them, and its ``refined`` times, :mod:`.refined`); ValueError if there is none."""
    counts: Counter[str] = Counter()
    payloads: dict[str, list[dict]] = {}
    counted: dict[str, dict[int, Counted[int]]] = {}
    losses: Losses[tuple[str, int]] = Losses()
    marks: list[Mark] = []
    name = None
    for entry in read_all(paths, reading) if entries is None else entries:
        if entry.after_damage:
            losses.unread()
        if entry.topic == STATUS:
            status = entry.payload()
            losses.status(status)
            for listed in status.get("nodes") or []:
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
        if where is None or where[0] != node:
            continue
        payload = entry.payload()
        if refined is not None:
            payload = refined.apply(entry, payload)
        kept = payloads.setdefault(where[1], [])
        _keep(counted, losses.add(node, where[1], payload, (where[1], len(kept))))
        if record and where[1] != record:
            continue  # (counted all the same: its seq and starts tell about the rest)
        counts[where[1]] += 1
        kept.append(payload)
    if not counts:
        what = f"record {record} of node {node}" if record else f"records of node {node}"
        raise ValueError(f"no {what} in {', '.join(map(str, paths))}")
    _keep(counted, losses.finish())
    chosen = record or counts.most_common(1)[0][0]
    rows = [counted[chosen][i] for i in range(len(payloads[chosen]))]
    return Found(chosen, payloads[chosen], name, marks,
                 Counts(rows, losses.period(node, chosen)))


def _keep(counted: dict[str, dict[int, Counted[int]]],
          decided: list[Counted[tuple[str, int]]]) -> None:
    for row in decided:
        record, index = row.item
        counted.setdefault(record, {})[index] = row._replace(item=index)


def count(payloads: list[dict]) -> Counts:
    """The losses of ``payloads`` taken as all of their node's messages."""
    stream: Stream[int] = Stream()
    rows = [row for i, p in enumerate(payloads) for row in stream.add(p, i, i + 1)]
    rows += stream.flush()
    return Counts(rows, stream.seconds)


def picture(node: int, record: str, payloads: list[dict], name: str | None,
            marks: list[Mark] | None = None, counts: Counts | None = None,
            window: bool = False, shows: str = "") -> Picture:
    """The panels, title and marks for ``payloads`` (one node's records of one kind),
    whose losses are ``counts`` (by default counted from the payloads alone). The marks
    drawn are those within the samples' time, or, for a ``window`` of the recordings
    (the marks given being the window's), all of them: a trial's closing mark comes
    after its last sample. ``shows``: which trial or window it is, said in the title
    (issue 43: a folder of plotted trials could not be told apart)."""
    counts = counts or count(payloads)
    clock = "time" if any(isinstance(p.get("time"), (int, float)) for p in payloads) \
        else "device_time"
    kept = [i for i, p in enumerate(payloads) if isinstance(p.get(clock), (int, float))]
    if not kept:
        raise ValueError(f"node {node}'s {record} records carry no time to plot against")
    rows = [payloads[i] for i in kept]
    lost = [counts.rows[i] for i in kept]
    start = rows[0][clock]
    x = [p[clock] - start for p in rows]
    steps = [b - a for a, b in itertools.pairwise(x) if b > a]
    period = counts.period or (statistics.median(steps) if steps else 0.0)
    gaps = {i for i in range(1, len(rows)) if lost[i].lost != 0
            or (period and x[i] - x[i - 1] > GAP_FACTOR * period)}
    panels = _panels(record, rows)
    if not panels:
        raise ValueError(f"node {node}'s {record} records hold no values to draw (all "
                         "NaN: a magnetometer an Inertia-Link does not have?)")
    summary = Summary()
    for row in lost:
        summary.add(row, period=period or None)
    who = f"{name} ({node})" if name else f"node {node}"
    rate = f"{1 / period:.1f} Hz" if period else "rate unknown"
    title = "\n".join([f"{who}: {record}, {rate}, {len(rows):,} records",
                       *([shows] if shows else []), summary.line(" · ")])
    when = timetext.at(timetext.nanoseconds(start)) if clock == "time" else "the node's timer"
    shown = [(mark.time - start, mark.text) for mark in marks or ()
             if clock == "time" and (window or x[0] <= mark.time - start <= x[-1])]
    return Picture(broken(x, panels, gaps), panels, title,
                   f"seconds from {when} ({clock})", shown, summary)


def wraps_of(values: list[float]) -> set[int]:
    """Indices where an angle (degrees) jumps by more than HALF_TURN from the one
    before: a wrap from +180 to -180 degrees, not a turn."""
    return {i for i in range(1, len(values)) if abs(values[i] - values[i - 1]) > HALF_TURN}


def broken(x: list[float], panels: list[Series], gaps: set[int]) -> list[float]:
    """``x`` with a point inserted before each index in ``gaps`` (NaN in x and every
    line: matplotlib breaks a line at a NaN) and before each wrap of an angle line (NaN
    in that line; x and the other lines at the midpoint, so they go on unbroken); the
    panels' lines are changed to match."""
    cuts = {(n, label): wraps_of(values) for n, panel in enumerate(panels) if panel.wraps
            for label, values in panel.lines.items()}
    wraps = set().union(*cuts.values()) - gaps
    inserted = gaps | wraps
    out: list[float] = []
    for i, at in enumerate(x):
        if i in gaps:
            out.append(NAN)
        elif i in wraps:
            out.append((x[i - 1] + at) / 2)
        out.append(at)
    for n, panel in enumerate(panels):
        for label, values in panel.lines.items():
            own = cuts.get((n, label), set())
            line: list[float] = []
            for i, value in enumerate(values):
                if i in inserted:
                    line.append(NAN if i in gaps or i in own else (values[i - 1] + value) / 2)
                line.append(value)
            panel.lines[label] = line
    return out


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(
        value, bool) else NAN


def _degrees(value: Any) -> float:
    return math.degrees(_number(value))


def _angles(matrix: Any) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees of an orientation matrix (NaN if it is not one)."""
    if not (isinstance(matrix, (list, tuple)) and len(matrix) == 3 and all(
            isinstance(row, (list, tuple)) and len(row) == 3 for row in matrix)):
        return NAN, NAN, NAN
    cells = [[_number(v) for v in row] for row in matrix]
    if any(math.isnan(v) for row in cells for v in row):
        return NAN, NAN, NAN
    return tuple(math.degrees(a) for a in euler_from_matrix(cells))  # type: ignore[return-value]


def _panels(record: str, rows: list[dict]) -> list[Series]:
    spec = BY_NAME.get(record)
    layout = ([(f.name, f.type.shape, f.doc) for f in spec.reply] if spec else
              [(k, "vector" if isinstance(v, list) else "float", "")
               for k, v in rows[0].items() if isinstance(v, (int, float, list))])
    panels: list[Series] = []
    by_unit: dict[str, Series] = {}
    for name, shape, units in layout:
        if name in SKIPPED or shape == "text":
            continue
        # a field's doc is its unit, then what else there is to say: "gauss; NaN on
        # an Inertia-Link", "A/D codes: accel, gyro_x, gyro_y, gyro_z" (what each is)
        unit, _, named = units.split(";")[0].partition(":")
        unit = unit.strip()
        if shape == "matrix":
            panel = Series(f"{name.replace('_', ' ')}\nas Euler angles", "deg", wraps=True)
            angles = [_angles(p.get(name)) for p in rows]
            for i, label in enumerate(EULER):
                panel.lines[label] = [a[i] for a in angles]
            panels.append(panel)
            continue
        if shape in ("vector", "ints"):
            values = [p.get(name) if isinstance(p.get(name), list) else [] for p in rows]
            size = max((len(v) for v in values), default=0)
            names = [n.strip() for n in named.split(",")]
            labels = (tuple(names) if len(names) == size and shape == "ints"
                      else ("x", "y", "z") if size == 3
                      else tuple(str(i + 1) for i in range(size)))
            panel = Series(name.replace("_", " "), unit)
            for i, label in enumerate(labels):
                panel.lines[label] = [_number(v[i]) if i < len(v) else NAN for v in values]
            panels.append(panel)
            continue
        if name in EULER:
            panel = by_unit.get("euler")
            if panel is None:
                panel = by_unit["euler"] = Series("Euler angles", "deg", wraps=True)
                panels.append(panel)
            panel.lines[name] = [_degrees(p.get(name)) for p in rows]
            continue
        key = unit or name
        panel = by_unit.get(key)
        if panel is None:
            panel = by_unit[key] = Series(name.replace("_", " "), unit)
            panels.append(panel)
        panel.lines[name] = [_number(p.get(name)) for p in rows]
    return [p for p in panels if any(not math.isnan(v) for vs in p.lines.values()
                                     for v in vs)]
