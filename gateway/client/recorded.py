"""Reading recordings as the live subscriber reads a gateway: the same :class:`Message`
(and, asked, :class:`Status`) objects, with the same fields, ``gap`` and ``restarted``,
from the gateway's MCAP files, so an analysis script is the same live and offline.

    from gateway.client import Recording

    with Recording("recordings/", nodes=[76], records=["accel_angrate"],
                   between_marks=("start", "stop"), trial=1) as sub:
        for message in sub:
            print(message.node, message.time, message["accel"], message.gap)

The window arguments are gx2ctl's (``start``/``stop`` for ``--from``/``--to``,
``between_marks``, ``trial``), read by :mod:`gateway.recording.window`: only the files
and chunks the window touches are read, a message met twice (a file given twice,
overlapping files) is yielded once. A recording holds NaN as null; a record is given
back as the gateway published it (:mod:`gateway.common.payloads`): its fields' NaN, and
a matrix's roll, pitch, yaw and quaternion where an older file lacks them. Damage is read past as
``gx2ctl export`` reads it: ``reading`` says what was skipped.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Iterable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.common.payloads import as_published
from gateway.common.topics import parse
from gateway.recording.catalogue import catalogue
from gateway.recording.files import MARK, STATUS, RecordingError, usable_files
from gateway.recording.marks import Mark
from gateway.recording.reader import Entry, read_all
from gateway.recording.refined import Refinement, check_refinable, check_time, for_window
from gateway.recording.reports import Reading
from gateway.recording.window import Asked, Reader, Window, check_held, touched, windows

from .messages import Event, Malformed, Numbering, Status

if TYPE_CHECKING:
    import pandas
    import pyarrow

log = logging.getLogger("gx2.client")


class Recording:
    """The records of recordings: ``paths`` a file, a directory (its ``*.mcap``) or
    several; ``nodes``/``records`` filter (empty: all); ``status=True`` also yields the
    recorded heartbeats. A window as gx2ctl takes one: ``start`` and ``stop`` (ISO 8601
    with a zone, seconds from the recordings' start, or a mark's text), or
    ``between_marks=(START, STOP)`` (every trial; ``trial=N`` the Nth, 1 the first).
    ``time="refined"``: each record's ``time`` placed after the fact, as ``gx2ctl export
    --time refined`` places it (the recordings are read once more for it, a window at
    a time, when iterated); ``"live"`` (the default), as recorded.

    RecordingError if no path is a recording; WindowError (a ValueError) for a window
    that cannot be taken, or nodes or records the recordings do not hold (a typo:
    ``records=["eulr"]``); ValueError for a ``time`` that is neither; Unrefinable (a
    RecordingError) for ``time="refined"`` of recordings without serial reads; each
    says why in one line, as gx2ctl does. The files are those found when it is made;
    iterating reads them again each time.
    """

    def __init__(self, paths: str | Path | Iterable[str | Path], nodes: Iterable[int] = (),
                 records: Iterable[str] = (), *, start: str | None = None,
                 stop: str | None = None, between_marks: tuple[str, str] | None = None,
                 trial: int | None = None, status: bool = False, time: str = "live") -> None:
        check_time(time)
        given = [paths] if isinstance(paths, (str, Path)) else list(paths)
        self.source = ", ".join(map(str, given))
        """What each message's ``gateway`` says: the paths as given."""
        self.paths = usable_files(given)
        self.nodes = frozenset(nodes)
        self.records = frozenset(records)
        self.yield_status = status
        asked = Asked(start, stop, tuple(between_marks) if between_marks else None,
                      trial, tuple(self.nodes))
        self.files = catalogue(self.paths, whole=asked.marked)
        # records the files do not hold are refused as nodes are (and as gx2ctl export
        # refuses both); the windows keep every record of the nodes asked, so a node's
        # seq is followed across the records left out, never taken for a gap
        check_held(replace(asked, records=tuple(sorted(self.records))), self.files)
        self.time = time
        """``live``: each record's ``time`` as recorded; ``refined``: placed after the
        fact from the recordings around it (:mod:`gateway.recording.refined`), each
        payload with ``time_placed`` and ``time_bound_ms``, as ``gx2ctl export --time
        refined`` writes them."""
        if time == "refined":
            check_refinable(self.files)
        self.windows: list[Window] = windows(asked, self.files)
        """One window, or one per trial (its ``label`` names it as export's folder)."""
        self.reading = Reading()
        """What reading met: ``reading.partial``, and ``reading.lines()`` saying what
        was skipped (a damaged chunk, a file that is not a recording)."""
        self.duplicates = 0
        """Messages met twice (a file given twice, overlapping files) and not yielded."""
        self._numbering = Numbering()
        self.lost = self._numbering.lost
        """Per (source, node): messages missing from the recordings (by ``seq``)."""
        self.restarts = self._numbering.restarts
        self.malformed = 0
        """Recorded messages on a node's topic that are not a record's JSON object."""

    def __iter__(self) -> Iterator[Event]:
        reader = Reader(self.files, self.reading)
        try:
            for window in self.windows:
                self._numbering.forget()  # (what lies between windows is not lost)
                refined = for_window(self.files, window) if self.time == "refined" else None
                for entry in reader.entries(window):
                    event = self._event(entry, refined)
                    if event is not None:
                        yield event
        finally:
            self.duplicates += reader.duplicates

    def _event(self, entry: Entry, refined: Refinement | None = None) -> Event | None:
        topic = entry.topic
        if topic == STATUS:
            return self.numbered_status(entry) if self.yield_status else None
        where = parse(topic)
        if where is None:
            return None  # marks, the serial channels
        node, record = where
        try:
            payload = as_published(entry.payload())
            if refined is not None:
                payload = refined.apply(entry, payload)
            return self._numbering.message(self.source, node, record, payload, topic,
                                           not self.records or record in self.records)
        except (RecordingError, Malformed) as problem:
            self.skipped(problem)
            return None

    def numbered_status(self, entry: Entry) -> Status | None:
        """A recorded heartbeat, its restart counted (None if it is not a JSON object)."""
        try:
            payload = entry.payload()
        except RecordingError:
            return None
        return Status(self.source, payload, self._numbering.started(self.source, payload))

    def skipped(self, problem: Exception) -> None:
        """A message on a node's topic that is not a record: counted, and said."""
        self.malformed += 1
        log.warning("%s: skipped a message: %s", self.source, problem)

    def trials(self) -> list[Recording]:
        """One Recording per window (per trial of ``between_marks``), in time order."""
        found = []
        for window in self.windows:
            one = copy.copy(self)
            one.windows = [window]
            one.reading, one.duplicates, one.malformed = Reading(), 0, 0
            one._numbering = Numbering()
            one.lost, one.restarts = one._numbering.lost, one._numbering.restarts
            found.append(one)
        return found

    def marks(self) -> list[Mark]:
        """The marks inside the windows (of the nodes asked, or of the whole
        experiment), in time order."""
        found = []
        for window in self.windows:
            for entry in read_all([d.path for d in touched(self.files, window)], Reading(),
                                  [MARK], window.span):
                mark = Mark.of(entry)
                if not self.nodes or not mark.nodes or self.nodes & set(mark.nodes):
                    found.append(mark)
        return sorted(set(found), key=lambda mark: mark.host_time)

    def to_pandas(self) -> pandas.DataFrame:
        """The records as one pandas DataFrame (:func:`gateway.client.to_pandas`)."""
        from .frames import to_pandas
        return to_pandas(self)

    def to_arrow(self) -> pyarrow.Table:
        """The records as one pyarrow Table, to_pandas's rows and columns in export's
        types, read a batch at a time (:mod:`gateway.client.arrows`)."""
        from .arrows import to_arrow
        return to_arrow(self)

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        pass
