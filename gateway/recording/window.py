"""Windows of recordings: a span of time (``--from``/``--to``, or each trial between
two marks), and a choice of nodes and records; the files a window touches, read by
seeking to the chunks it needs, each message once however often it is met.

A message is in a window when its log_time (the time it was read: a record's
``host_time``) is at or after the window's start and before its end. A bound given as
a mark's text is that mark's log_time, and a window ending at a mark holds the mark."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime

from gateway.common.timetext import ISO, UTC, at
from gateway.common.topics import parse

from .blocks import Block, entries_of
from .catalogue import Described, Marked, span_of
from .files import NS_LIMIT
from .reader import Entry, Span, read_blocks
from .reports import Reading

MARKS_LISTED = 10
"""At most this many marks are named when a mark text is not found."""


class WindowError(ValueError):
    """A window that cannot be taken: one line for the user (exit 2)."""


@dataclass(frozen=True)
class Asked:
    """A window as the user gave it (each part optional)."""

    start: str | None = None
    stop: str | None = None
    between: tuple[str, str] | None = None
    trial: int | None = None
    nodes: tuple[int, ...] = ()
    records: tuple[str, ...] = ()
    names: tuple[str, str, str, str] = ("--from", "--to", "--between-marks", "--trial")
    """What the user wrote for start, stop, between and trial, as errors name them
    (a replay URL's keys: from, to, between, trial)."""

    @property
    def marked(self) -> bool:
        """Whether the window is named by marks (the files' marks must be read)."""
        return self.between is not None or any(
            text is not None and _named(text) for text in (self.start, self.stop))


@dataclass(frozen=True)
class Window:
    """A span of log_time (None: all of it) and the node topics kept (others, the
    status, marks and serial channels, are always kept)."""

    span: Span | None = None
    nodes: frozenset[int] = frozenset()
    records: frozenset[str] = frozenset()
    label: str = ""
    """A trial's name (``trial-1_2026-11-25T10-00-00Z``); empty for a single window."""
    title: str = ""
    """What it is, for a person (a plot's title): ``trial 2 of 3: mark 'start' to mark
    'stop', 2026-11-25 10:40:00.000 to 10:41:00.000 UTC``; empty for all of the files."""

    def keeps(self, topic: str) -> bool:
        where = parse(topic)
        if where is None:
            return True
        return (not self.nodes or where[0] in self.nodes) and (
            not self.records or where[1] in self.records)


def when(stamp: int) -> str:
    """A log_time (ns) as ISO 8601, UTC, to the millisecond (as ``--from`` takes it)."""
    return at(stamp, ISO, zone="Z")


def _marks(files: list[Described]) -> list[Marked]:
    """Every mark of the files, once each, in time order."""
    return sorted({(m.log_time, m.text): m for d in files for m in d.marks}.values(),
                  key=lambda m: m.log_time)


def _listed(marks: list[Marked]) -> str:
    texts = list(dict.fromkeys(m.text for m in marks))
    if not texts:
        return "the recordings hold no marks"
    more = f" and {len(texts) - MARKS_LISTED} more" if len(texts) > MARKS_LISTED else ""
    return "marks: " + ", ".join(repr(t) for t in texts[:MARKS_LISTED]) + more


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def dated(text: str) -> bool:
    """Whether a bound is written as a date (else it names a mark)."""
    return text[:4].isdigit() and text[4:5] == "-"


def _named(text: str) -> bool:
    return _number(text) is None and not dated(text)


def bound(text: str, origin: int | None, marks: list[Marked], end: bool,
          name: str = "") -> int:
    """A ``--from``/``--to`` (``name``) as a log_time (ns): ISO 8601 with a zone,
    seconds from ``origin`` (the recordings' start), or the first mark with that text."""
    name = name or ("--to" if end else "--from")
    seconds = _number(text)
    if seconds is not None:
        if not math.isfinite(seconds) or origin is None:
            raise WindowError(f"{name} {text}: not a time in these recordings")
        if abs(seconds) * 1e9 >= NS_LIMIT:
            raise WindowError(f"{name} {text}: seconds from the recordings' start beyond "
                              "what any recording holds (it ends by 1.8e10 s)")
        return origin + round(seconds * 1e9)
    if dated(text):
        try:
            # (a lowercase z is UTC's too: 2026-11-25t10:00:00z)
            moment = datetime.fromisoformat(text[:-1] + "Z" if text.endswith("z") else text)
        except ValueError:
            raise WindowError(f"{name} {text}: not an ISO 8601 time") from None
        if moment.tzinfo is None:
            raise WindowError(f"{name} {text}: give the time's zone (Z, or +01:00 ...)")
        return round(moment.timestamp() * 1e9)
    for mark in marks:
        if mark.text == text:
            return mark.log_time + (1 if end else 0)
    raise WindowError(f"{name} {text}: no such mark ({_listed(marks)})")


def held(files: list[Described]) -> str:
    """What node records the files hold, for a line: ``node 11: accel_angrate, euler;
    node 12: ...``."""
    nodes: dict[int, set[str]] = {}
    for described in files:
        for node, records in described.nodes.items():
            nodes.setdefault(node, set()).update(records)
    if not nodes:
        return "they hold no node records"
    return "they hold " + "; ".join(f"node {node}: {', '.join(sorted(records))}"
                                    for node, records in sorted(nodes.items()))


def check_held(asked: Asked, files: list[Described], known: bool = False) -> None:
    """WindowError if no file holds a record of the nodes and records asked (told only
    where every file's are known, or ``known``: the files were read)."""
    if not (asked.nodes or asked.records):
        return
    if not known and not all(d.counted for d in files):
        return
    if any((not asked.nodes or node in asked.nodes)
           and (not asked.records or record in asked.records)
           for d in files for node, records in d.nodes.items() for record in records):
        return
    given = [f"--node {n}" for n in asked.nodes] + [f"--record {r}" for r in asked.records]
    raise WindowError(f"{' '.join(given)}: not in the recordings ({held(files)})")


def trials(start: str, stop: str, marks: list[Marked]) -> list[Span]:
    """Each trial: from a mark ``start`` to the next mark ``stop`` (both held); a
    ``start`` while a trial is open does not start another."""
    found: list[Span] = []
    opened: int | None = None
    for mark in marks:
        if mark.text == start and opened is None:
            opened = mark.log_time
        elif mark.text == stop and opened is not None:
            found.append((opened, mark.log_time + 1))
            opened = None
    return found


def unclosed(between: tuple[str, str], files: list[Described]) -> str:
    """A line about a trial started and never stopped (the last mark ``start`` with no
    mark ``stop`` after it: no trial, as trials has it); empty if there is none."""
    start, stop = between
    opened: Marked | None = None
    for mark in _marks(files):
        if mark.text == start and opened is None:
            opened = mark
        elif mark.text == stop:
            opened = None
    if opened is None:
        return ""
    return (f"the mark {start!r} at {when(opened.log_time)} has no mark {stop!r} after "
            "it: not a trial")


def _span_text(start: int | None, stop: int | None) -> str:
    """A window's span as every time is shown: ``2026-11-25 10:40:00.000 to
    10:41:00.000 UTC`` (the day once if it is the same), an open end said so."""
    first = at(start) if start is not None else "the start"
    last = at(stop) if stop is not None else "the end"
    if start is not None and stop is not None and first[:10] == last[:10]:
        last = last[11:]
    return f"{first.removesuffix(UTC) if stop is not None else first} to {last}"


def _label(number: int, span: Span) -> str:
    return f"trial-{number}_{at(span[0], ISO.replace(':', '-'), digits=0, zone='Z')}"


def windows(asked: Asked, files: list[Described]) -> list[Window]:
    """The windows asked of the recordings ``files`` (sorted as the catalogue sorts):
    one, or one per trial; WindowError for one that cannot be taken."""
    check_held(asked, files)
    nodes, records = frozenset(asked.nodes), frozenset(asked.records)
    everything = span_of(files)
    marks = _marks(files)
    name_from, name_to, name_between, name_trial = asked.names
    if asked.between is not None:
        if asked.start or asked.stop:
            raise WindowError(f"{name_between} takes the place of {name_from} and {name_to}")
        found = trials(*asked.between, marks)
        if not found:
            raise WindowError(f"no trial from a mark {asked.between[0]!r} to a mark "
                              f"{asked.between[1]!r} ({_listed(marks)})")
        numbered = list(enumerate(found, 1))
        if asked.trial is not None:
            if not 1 <= asked.trial <= len(found):
                raise WindowError(f"{name_trial} {asked.trial}: there are {len(found)} "
                                  f"trial{'s' * (len(found) != 1)} (1 is the first)")
            numbered = [numbered[asked.trial - 1]]
        a, b = asked.between
        return [Window(span, nodes, records, _label(n, span),
                       f"trial {n} of {len(found)}: mark {a!r} to mark {b!r}, "
                       f"{_span_text(span[0], span[1] - 1)}") for n, span in numbered]
    if asked.trial is not None:
        raise WindowError(f"{name_trial} picks one of the trials of {name_between}")
    if not (asked.start or asked.stop):
        return [Window(None, nodes, records)]
    origin = everything[0] if everything else None
    start = bound(asked.start, origin, marks, False, name_from) if asked.start else 0
    stop = bound(asked.stop, origin, marks, True, name_to) if asked.stop else 2 ** 64
    if asked.start and asked.stop and stop <= start:
        raise WindowError(f"{name_to} ({when(stop)}) is not after {name_from} "
                          f"({when(start)})")
    if everything is None or stop <= everything[0] or start > everything[1]:
        held = (f"the recordings span {when(everything[0])} to {when(everything[1])}"
                if everything else "the recordings hold no messages")
        raise WindowError(f"the window {when(start) if asked.start else '(start)'} to "
                          f"{when(stop) if asked.stop else '(end)'} is outside every file: "
                          f"{held}")
    return [Window((start, stop), nodes, records, title="window " + _span_text(
        start if asked.start else None, stop if asked.stop else None))]


def touched(files: list[Described], window: Window) -> list[Described]:
    """The files the window's span touches (with those whose span is not known: they
    are read to be said unreadable)."""
    span = window.span
    if span is None:
        return list(files)
    return [d for d in files if d.start is None or d.end is None
            or (d.end >= span[0] and d.start < span[1])]


def _shared(described: Described, later: list[Described]) -> frozenset[str] | None:
    """The topics of ``described`` a later file that overlaps it may hold again (None:
    any, a file's topics not being known): only their messages need be remembered."""
    overlapping = [d for d in later if d.start is None or described.end is None
                   or d.start <= described.end]
    if described.topics is None or any(d.topics is None for d in overlapping):
        return None
    return described.topics & frozenset().union(*(d.topics for d in overlapping))


def _key(log_time: int, topic: str, data: bytes) -> int:
    """A message's log_time and a 64-bit hash of its topic and data, as one integer
    (under 200 bytes remembered a message, with the set's own, where the message
    itself took 500): two messages that differ, logged at the same nanosecond, whose
    hashes are the same, are not met in practice."""
    return log_time << 64 | hash((topic, data)) & _HASH_BITS


_HASH_BITS = (1 << 64) - 1


class Reader:
    """Reads windows of the catalogued files ``files`` (sorted by start), dropping
    each message met again (same topic, log_time and data), and counting them. Only
    the messages a later file overlapping may hold again are remembered (those after
    its start, on the topics it holds too), each as a compact key (:func:`_key`)."""

    def __init__(self, files: list[Described], reading: Reading) -> None:
        self._files = files
        self._reading = reading
        self.duplicates = 0
        self.duplicate_records = 0
        """Of them, the nodes' records (a table's rows; the rest are statuses, marks and
        serial reads)."""
        self.remembered = 0
        """The most messages remembered at once (to tell duplicates)."""

    def entries(self, window: Window) -> Iterator[Entry]:
        """The window's messages, one at a time."""
        return entries_of(self.blocks(window))

    def blocks(self, window: Window) -> Iterator[Block]:
        """The window's messages, a chunk at a time (a message met again left out)."""
        chosen = touched(self._files, window)
        seen: set[int] = set()
        seen_until = -1
        """The last log_time of the files read: a message after it is not met twice."""
        damaged = False  # (a skipped stretch before messages left out: said by the next)
        for i, described in enumerate(chosen):
            later = [d.start for d in chosen[i + 1:] if d.start is not None]
            keep_from = min(later) if later else None
            shared = _shared(described, chosen[i + 1:])
            if described.start is not None:  # nothing before this start comes again
                seen = {key for key in seen if key >> 64 >= described.start}
            for block in read_blocks(described.path, self._reading, span=window.span):
                damaged = damaged or block.after_damage
                block = block.kept(channels=block.on(window.keeps))
                keep = self._once(block, seen, seen_until, keep_from, shared)
                if keep is not None:
                    block = block.taken(keep)
                if len(block):
                    yield block.marked(damaged)
                    damaged = False
            if described.end is not None:
                seen_until = max(seen_until, described.end)

    def _once(self, block: Block, seen: set[int], seen_until: int, keep_from: int | None,
              shared: frozenset[str] | None) -> list[int] | None:
        """Where the block's messages not met before are, the others counted; those a
        later file may hold again remembered. Only messages logged by ``seen_until`` (the
        end of the files read) can have been met, and only those from ``keep_from`` (a
        later file's start) met again: None, all kept, when the block holds neither."""
        times = block.log_time
        if not len(times) or (min(times) > seen_until and (
                keep_from is None or max(times) < keep_from)):
            return None
        kept = []
        for i, (channel, log_time, data) in enumerate(zip(block.channel, times, block.data,
                                                          strict=True)):
            check = log_time <= seen_until
            later = keep_from is not None and log_time >= keep_from
            if check or later:
                topic = block.topics[channel]
                key = _key(log_time, topic, data)
                if check and key in seen:
                    self.duplicates += 1
                    self.duplicate_records += parse(topic) is not None
                    continue
                if later and (shared is None or topic in shared):
                    seen.add(key)
            kept.append(i)
        self.remembered = max(self.remembered, len(seen))
        return kept
