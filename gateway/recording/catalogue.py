"""What recordings hold, without reading their messages where it can be helped: each
file's span, size, stations, nodes and records with their message counts, and its
marks (``gx2ctl recordings``; the spans also choose the files a window reads).

A finished file is described from its summary (statistics and chunk indexes); its
marks are read from the chunks that hold the mark channel only. A file without a whole
summary (its writer killed, cut short, damaged) or without statistics is read through,
past any damage, as export reads it, and says so (``indexed`` false; ``cut_short``,
``damaged``); but the file a writer holds open (``writing``) may be described by its
chunks' headers only, as any file is when only its span is asked, and its marks
from the chunks whose message indexes say they hold one."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.common.topics import default_station_name, parse

from .files import MARK, SERIAL_READS, WRITTEN, being_written, is_serial_reads
from .index import walked_span
from .marks import Mark
from .reader import index_of, read, read_blocks
from .reports import Reading


@dataclass(frozen=True)
class Marked:
    """A mark as the catalogue gives it: its time, its text, and its log_time (ns,
    the time a window named by it starts or ends at)."""

    time: float
    text: str
    log_time: int
    fields: tuple[tuple[str, str], ...] = ()
    """What its maker said of it (``gx2ctl mark --field KEY=VALUE``)."""


@dataclass
class Described:
    """One recording file."""

    path: Path
    bytes: int
    start: int | None = None
    """log_time (ns) of its first message and of its last; None: it holds none."""
    end: int | None = None
    stations: list[str] = field(default_factory=list)
    nodes: dict[int, dict[str, int]] = field(default_factory=dict)
    marks: list[Marked] = field(default_factory=list)
    damaged: bool = False
    """Something in it could not be read (the reader's report says what)."""
    cut_short: bool = False
    """Its writer stopped without finishing it: it ends at its last whole chunk."""
    writing: bool = False
    """A writer has it open (a running gateway's or gx2ctl record's file): it ends at
    its last flush, and is not cut short."""
    indexed: bool = False
    """Described from its summary, its messages unread (but for its marks)."""
    topics: frozenset[str] | None = None
    """The topics of its messages (None: not known, a file without summary whose span
    only was asked)."""
    counted: bool = True
    """Its nodes and records are known (False: only its span was asked, and it has no
    summary to tell them without reading it through)."""
    how: str = "no summary: read through"
    """How it was described, where not from its summary (not ``indexed``)."""
    problem: str = ""
    """The reader's line about it (empty: it read whole)."""
    overlaps: list[Path] = field(default_factory=list)
    """Files given whose spans overlap this one's."""
    same_as: list[Path] = field(default_factory=list)
    """Files given that are this one again (the same file, or the same span, size and
    counts: a copy)."""

    def json(self) -> dict[str, Any]:
        return {"path": str(self.path), "start": _seconds(self.start),
                "end": _seconds(self.end), "bytes": self.bytes, "stations": self.stations,
                "nodes": {str(node): records for node, records in sorted(self.nodes.items())},
                "marks": [{"time": mark.time, "text": mark.text, "fields": dict(mark.fields)}
                          for mark in self.marks],
                "damaged": self.damaged, "cut_short": self.cut_short,
                "writing": self.writing,
                "indexed": self.indexed, "overlaps": [str(p) for p in self.overlaps],
                "same_as": [str(p) for p in self.same_as]}

    def _key(self) -> tuple[Any, ...]:
        return (self.start, self.end, self.bytes, json.dumps(self.nodes, sort_keys=True))


def _seconds(stamp: int | None) -> float | None:
    return None if stamp is None else stamp / 1e9


def _station(topic: str) -> str | None:
    if not is_serial_reads(topic):
        return None
    return default_station_name(0) if topic == SERIAL_READS else topic[len(SERIAL_READS) + 1:]


def _counted(described: Described, counts: dict[str, int]) -> None:
    stations = set()
    for topic, count in counts.items():
        where = parse(topic)
        if where is not None:
            records = described.nodes.setdefault(where[0], {})
            records[where[1]] = records.get(where[1], 0) + count
        elif (station := _station(topic)) is not None and topic != WRITTEN:
            stations.add(station)
    described.stations = sorted(stations)
    described.nodes = {node: dict(sorted(records.items()))
                       for node, records in sorted(described.nodes.items())}


def _marked(entry: Any) -> Marked:
    mark = Mark.of(entry)
    return Marked(mark.time, mark.text, entry.log_time, mark.fields)


def describe(path: Path, whole: bool = True, read_writing: bool = True) -> Described:
    """One file: from its summary (and its mark chunks) if it has a whole one, else
    read through (so is a finished file without statistics, to count its messages).
    Not ``whole``: its span only, and no mark (what a window of times and a read
    without a window need: the summary, else the chunks' headers; so a file without
    summary is not read twice), but for a file whose framing breaks (read through: its
    span past the break is only known so). Not ``read_writing``: a file being
    written is described by its span and its marks (read from the chunks that hold
    them) only (it may be an hour's data: its counts are known when it is finished)."""
    described = Described(path, path.stat().st_size if path.exists() else 0)
    index, report = index_of(path)
    reading = Reading()
    if index is not None and (index.messages is not None or not whole):
        described.indexed = True
        described.start, described.end = index.start, index.end  # (or its chunks')
        _counted(described, index.topic_counts())
        described.topics = frozenset(index.channels.values())
        described.counted = index.messages is not None
        if not whole:
            return described
        described.marks = [_marked(entry) for entry in read(path, reading, [MARK])]
    else:
        if index is not None:
            described.how = "its summary has no statistics (message counts): read through"
        elif (not whole or (not read_writing and being_written(path))) and (
                report.skipped or (walked := walked_span(path)).whole):
            # (a file whose framing breaks is read through: past the break, the
            # reader finds messages its chunks' headers could not tell of)
            if not report.skipped and walked.span is not None:
                described.start, described.end = walked.span
            described.counted = bool(report.skipped)
            described.writing = not report.skipped and being_written(path)
            if described.writing:
                described.how = ("being written: its span from its chunks' headers (its "
                                 "counts once it is finished)")
                if whole:  # its marks, from the chunks that hold them (issue 43: a trial
                    # marked now was not listed until the file rotated, up to an hour)
                    described.marks = [_marked(entry)
                                       for entry in read(path, reading, [MARK])]
                    if (marked := reading.files[0]).partial:
                        described.damaged, described.problem = True, marked.line()
            return described
        _read_through(described, reading)
    report = reading.files[0]
    described.damaged = report.partial
    described.writing = report.writing
    described.cut_short = not report.skipped and not report.whole and not report.writing
    described.problem = report.line()
    return described


def _read_through(described: Described, reading: Reading) -> None:
    """Its span, counts and marks, from every message of it (a chunk at a time: its
    channels counted, its times' bounds taken, its marks alone made messages)."""
    counts: dict[str, int] = {}
    for block in read_blocks(described.path, reading):
        for channel, count in Counter(block.channel).items():
            topic = block.topics[channel]
            counts[topic] = counts.get(topic, 0) + count
        first, last = min(block.log_time), max(block.log_time)
        described.start = first if described.start is None else min(described.start, first)
        described.end = last if described.end is None else max(described.end, last)
        if MARK in block.topics.values():
            marks = block.kept(channels=block.on(MARK.__eq__))
            described.marks += [_marked(entry) for entry in marks.entries()]
    _counted(described, counts)
    described.topics = frozenset(counts)


def catalogue(paths: Iterable[Path], whole: bool = True, read_writing: bool = True
              ) -> list[Described]:
    """The files, described (``whole``, ``read_writing``: see describe), sorted by
    their start (those holding nothing last), with overlapping and repeated files said."""
    found = sorted((describe(path, whole, read_writing) for path in paths),
                   key=lambda d: (d.start is None, d.start or 0, str(d.path)))
    for i, one in enumerate(found):
        for other in found[i + 1:]:
            if one.start is None or other.start is None or other.start > one.end:  # type: ignore[operator]
                continue
            if _same(one, other):
                one.same_as.append(other.path)
                other.same_as.append(one.path)
            else:
                one.overlaps.append(other.path)
                other.overlaps.append(one.path)
    return found


def _same(one: Described, other: Described) -> bool:
    try:
        if one.path.samefile(other.path):
            return True
    except OSError:
        pass
    return one._key() == other._key()


def span_of(described: list[Described]) -> tuple[int, int] | None:
    """(first, last) log_time (ns) over files; None if none holds a message."""
    starts = [d.start for d in described if d.start is not None]
    ends = [d.end for d in described if d.end is not None]
    return (min(starts), max(ends)) if starts and ends else None
