"""``time`` refined after the fact, for export and the client (``--time refined``,
``Recording(..., time="refined")``).

Live, a record's ``time`` can use only the packets read before it: while a node's
packets all wait behind another's on the serial line, the host cannot see where its
samples fall (issue 32). A recording holds what came after too; :mod:`aspp.refine`
places each power-up's records from the sightings of its floor on both sides of them,
and keeps the live ``time`` where no two sightings bracket a record. What it is fed
comes from the recording's serial reads (:mod:`.sightings`), so a recording without
them (``gx2ctl record``'s: a subscriber never sees the bytes) cannot be refined: that
is an error (:class:`Unrefinable`), not the live ``time`` given under another name.

The records of a window are refined from the window and MARGIN either side of it (a
trial between two marks is placed by the sightings around it too). Each row gains
``time_placed`` (:class:`aspp.refine.Placement`'s value: ``between``, ``one_side``,
``live``, ``unplaceable``) and ``time_bound_ms``, how far from the floor its time may
be (empty where none is known: ``live``, ``unplaceable``).

Two passes: this one reads the recordings whole before the rows are written (the
future is what it knows), and the export's reads them again; each topic's rows are met
in the same order both times, and a row's times are checked against its message's.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.records import Header, Metadata
from mcap.stream_reader import StreamReader

from aspp.refine import REACH, Placement, refine
from aspp.timing import BITS_PER_BYTE
from gateway.common.topics import parse

from .catalogue import Described
from .files import METADATA, RecordingError, is_serial_reads
from .reader import Entry, Span
from .reports import Reading
from .sightings import LineSettings, Sightings
from .tables import BOUND, PLACED
from .window import Reader, Window, touched

TIMES = ("live", "refined")
"""What ``time`` may be: as recorded (the default), or refined after the fact."""
LOOKAHEAD = 8
"""Rows of a topic a row is looked for among, from the one after the last found (the
two passes read the same rows in the same order: the first is the one). One not among
them is looked up by its log_time: the first pass read more than the second (a
dataset's recording refined from the recordings around it, one of them overlapping
it)."""
MARGIN = 2 * REACH
"""Seconds of the recordings either side of a window read for its sightings."""
DEFAULT = LineSettings(BITS_PER_BYTE / 115200, 3e-3)
"""A line whose recording does not say it (another writer's head): the configuration's
defaults, 115200 baud and latency_ms 3."""


class Unrefinable(RecordingError):
    """Recordings whose times cannot be refined: one line saying why."""


def check_time(time: str) -> None:
    """ValueError (one line) for a ``time`` that is none of TIMES."""
    if time not in TIMES:
        raise ValueError(f"time must be one of {', '.join(map(repr, TIMES))}, not {time!r}")


def widened(span: Span | None) -> Span | None:
    """The span read for a window's sightings."""
    if span is None:
        return None
    margin = int(MARGIN * 1e9)
    return max(0, span[0] - margin), span[1] + margin


def line_settings(paths: Iterable[Path]) -> dict[str, LineSettings]:
    """Per serial channel, its line as the gateway that wrote the files had it (the
    first file that says wins: a configuration rarely changes between files)."""
    found: dict[str, LineSettings] = {}
    for path in paths:
        head = _head(path)
        if head is None:
            continue
        stations = json.loads(head.get("stations", "[]"))
        if stations:
            for station in stations:
                found.setdefault(f"serial/{station['name']}",
                                 _settings(station.get("baudrate"), station.get("latency_ms")))
        else:
            found.setdefault("serial", _settings(head.get("baudrate"), head.get("latency_ms")))
    return found


def _head(path: Path) -> dict[str, str] | None:
    try:
        with path.open("rb") as stream:
            for record in StreamReader(stream, emit_chunks=True).records:
                if isinstance(record, Metadata) and record.name == METADATA:
                    return dict(record.metadata)
                if not isinstance(record, Header):
                    return None  # (the gateway writes its metadata first)
    except Exception:  # (a head that does not read says nothing: the defaults hold)
        return None
    return None


def _settings(baudrate: Any, latency_ms: Any) -> LineSettings:
    try:
        byte_time = BITS_PER_BYTE / float(baudrate)
    except (TypeError, ValueError, ZeroDivisionError):
        byte_time = DEFAULT.byte_time
    try:
        latency = float(latency_ms) / 1000
    except (TypeError, ValueError):
        latency = DEFAULT.latency
    return LineSettings(byte_time, latency)


Placed = tuple[float, str, float | None]
"""A row's refined time: UNIX seconds, how it was placed, its bound (ms)."""


class Refinement:
    """The refined time of each row of a window, handed out in the order the rows are
    read again (:meth:`apply`), each checked against its message's log_time."""

    def __init__(self, rows: dict[str, list[tuple[int, Placed | None]]]) -> None:
        self._rows = rows
        self._next: dict[str, int] = {}
        self._stamps: dict[str, dict[int, list[int]]] = {}
        """Each topic's rows by log_time (made when a row is first missed)."""

    def apply(self, entry: Entry, payload: dict[str, Any]) -> dict[str, Any]:
        """``payload`` (a record's, read from ``entry``) with its refined ``time`` and
        the two columns: empty for an untimed record; a timed one not refined (its
        packet not found, or the row not met in the first pass) keeps its time, placed
        ``live``."""
        rows = self._rows.get(entry.topic, ())
        at = self._next.get(entry.topic, 0)
        found = None
        for i in range(at, min(at + LOOKAHEAD, len(rows))):
            if rows[i][0] == entry.log_time:
                found, self._next[entry.topic] = rows[i][1], i + 1
                break
        else:
            i = self._stamped(entry.topic, entry.log_time, at)
            if i is not None:
                found, self._next[entry.topic] = rows[i][1], i + 1
        if "time" not in payload:
            payload[PLACED] = payload[BOUND] = None
        elif found is None:
            payload[PLACED], payload[BOUND] = Placement.LIVE.value, None
        else:
            payload["time"], payload[PLACED], payload[BOUND] = found
        return payload


    def _stamped(self, topic: str, stamp: int, at: int) -> int | None:
        """The topic's row at log_time ``stamp``, the first from ``at`` on (else the
        first); None if there is none."""
        by_stamp = self._stamps.get(topic)
        if by_stamp is None:
            by_stamp = self._stamps[topic] = {}
            for i, (row_stamp, _) in enumerate(self._rows.get(topic, ())):
                by_stamp.setdefault(row_stamp, []).append(i)
        found = by_stamp.get(stamp)
        if not found:
            return None
        return next((i for i in found if i >= at), found[0])


def check_refinable(files: list[Described]) -> None:
    """Unrefinable, before anything is read, if the catalogue already shows that no
    file holds serial reads (where a file's topics are not known yet, the reading
    says: :func:`refinement`)."""
    if files and all(d.topics is not None and not any(map(is_serial_reads, d.topics))
                     for d in files):
        raise Unrefinable(_unrefinable(str(files[0].path) if len(files) == 1
                                       else f"{len(files)} recordings"))


def _unrefinable(where: str) -> str:
    return (f"{where}: no serial reads, and the refined time needs them (which packets "
            "waited on the line): a file of gx2ctl record's holds only what was "
            "published; take the time as recorded (live), or the gateway's own recording")


def for_window(files: list[Described], window: Window) -> Refinement:
    """The refined times of the rows of ``window`` of the catalogued ``files``, from
    their messages in the window widened by MARGIN (every record of its nodes: the
    clock is fed by them all). Unrefinable if they hold no serial read."""
    wide = Window(widened(window.span), window.nodes)
    paths = [d.path for d in touched(files, wide)]
    where = str(paths[0]) if len(paths) == 1 else f"{len(paths)} recordings"
    return refinement(Reader(files, Reading()).entries(wide), line_settings(paths),
                      window, where)


def refinement(entries: Iterator[Entry], lines: dict[str, LineSettings],
               window: Window, where: str) -> Refinement:
    """The refined times of the rows ``window`` keeps, read from ``entries`` (its
    messages and those around it). Unrefinable if they hold no serial read (``where``
    names the recordings in its line)."""
    sightings = Sightings(lines, DEFAULT)
    low, high = window.span or (0, 2 ** 64)
    for entry in entries:
        if is_serial_reads(entry.topic):
            sightings.feed(entry.topic, entry.log_time, entry.publish_time, entry.data,
                           None, False)
        elif parse(entry.topic) is not None:
            try:
                payload = entry.payload()
            except RecordingError:
                continue  # (the export's pass says so, or skips it as it always has)
            sightings.feed(entry.topic, entry.log_time, entry.publish_time, entry.data,
                           payload, low <= entry.log_time < high
                           and window.keeps(entry.topic))
    if not sightings.reads:
        raise Unrefinable(_unrefinable(where))
    placed: dict[int, tuple[list[float], list[Placement], list[float | None]]] = {}
    for power_up in sightings.power_ups:
        order = sorted(range(len(power_up.device)), key=power_up.device.__getitem__)
        out = refine([(power_up.device[i], power_up.arrival[i], power_up.waited[i])
                      for i in order], [power_up.live[i] for i in order])
        times: list[float] = [0.0] * len(order)
        how: list[Placement] = [Placement.LIVE] * len(order)
        bounds: list[float | None] = [None] * len(order)
        for k, i in enumerate(order):
            times[i] = out.line[k] + power_up.shift[i]
            how[i], bounds[i] = out.placement[k], out.bound[k]
        placed[id(power_up)] = (times, how, bounds)
    rows = {topic: [(stamp, None if power_up is None else _placed(placed[id(power_up)], i))
                    for stamp, power_up, i in found]
            for topic, found in sightings.rows.items()}
    return Refinement(rows)


def _placed(placed: tuple[list[float], list[Placement], list[float | None]],
            i: int) -> Placed:
    times, how, bounds = placed
    bound = bounds[i]
    return times[i], how[i].value, None if bound is None else round(bound * 1e3, 3)
