"""What reading recordings met: per file, what was skipped and what that held, in one
line for the user."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from gateway.common.timetext import at


@dataclass
class Loss:
    """A stretch of a file skipped as unreadable, and what is known of what it held."""

    offset: int
    size: int
    chunk: bool
    """It is a chunk (its record's framing held), not bytes no record could be read from."""
    messages: int | None = None
    """Counted from the message index written after the chunk; None: not known."""
    after: int | None = None
    """log_time (ns) of the last message read before it."""
    before: int | None = None
    """log_time (ns) of the first message read after it."""


@dataclass
class FileReport:
    """What reading one file met: why it was skipped whole, or what was skipped in it."""

    path: Path
    skipped: str = ""
    losses: list[Loss] = field(default_factory=list)
    orphans: int = 0
    """Messages on a channel whose definition was in a damaged chunk."""
    read: int = 0
    """Messages read (of every topic, wanted or not)."""
    expected: int | None = None
    """The message count a finished file's summary gives."""
    whole: bool = False
    """Its data section ends where a finished file's does: it was not cut short."""
    last: int | None = None
    """log_time (ns) of the last message read."""
    writing: bool = False
    """Not whole because a writer has it open (:func:`.files.being_written`): it ends
    at its writer's last flush, not cut short."""
    passed: int | None = None
    """The latest log_time (ns) of the chunks a window read passed over unread (their
    headers'): a file cut short ends at the later of it and ``last``."""
    decompressed: int = 0
    """Chunks decompressed (a window read passes over the others unread)."""
    summary: str = ""
    """What was wrong with a finished file's footer or summary: every record was read
    all the same (the data section's end found from the records), so it is said, but
    nothing was skipped for it."""

    @property
    def partial(self) -> bool:
        """Something in it could not be read (a file cut short is not, by itself)."""
        return bool(self.skipped or self.losses or self.orphans)

    def line(self) -> str:
        """One line for the user; empty for a file read whole."""
        if self.skipped:
            return f"{self.path}: skipped: {self.skipped}"
        said = [self.summary] if self.summary else []
        if self.losses or self.orphans:
            said.append(self._damage())
        if not self.whole:
            ends = max((t for t in (self.last, self.passed) if t is not None), default=None)
            said.append(f"being written: its last flush {_after(ends)}" if self.writing
                        else f"ends early {_after(ends)} (its writer was stopped without "
                        "warning)")
        if not said:
            return ""
        return f"{self.path}: {'; '.join(said)}; read " + (
            "the rest" if self.losses or self.orphans else
            "up to there" if not self.whole else "every message")

    def joined(self, other: FileReport) -> FileReport:
        """This file's report and another of the same file (read again for another
        window: each trial of an export reads the files it touches) as one: what
        either skipped, and where the later read found the file ending."""
        offsets = {loss.offset for loss in self.losses}
        whole = self.whole and other.whole
        return FileReport(
            self.path, self.skipped or other.skipped,
            [*self.losses, *(loss for loss in other.losses if loss.offset not in offsets)],
            max(self.orphans, other.orphans), max(self.read, other.read),
            self.expected if self.expected == other.expected else None, whole,
            _latest(self.last, other.last), (self.writing or other.writing) and not whole,
            _latest(self.passed, other.passed), self.decompressed + other.decompressed,
            self.summary or other.summary)

    def _damage(self) -> str:
        chunks = sum(loss.chunk for loss in self.losses)
        stray = sum(loss.size for loss in self.losses if not loss.chunk)
        what = [f"{chunks} damaged chunk{'s' * (chunks != 1)}"] if chunks else []
        if stray:
            what.append(f"{stray:,} unreadable bytes")
        if self.orphans:
            what.append(f"{self.orphans:,} messages on channels defined in what was lost")
        held = []
        if self.losses:
            held += [self._messages_lost(),
                     f"{sum(loss.size for loss in self.losses):,} bytes"]
            held += [span for loss in self.losses if (span := _span(loss.after, loss.before))]
        return f"skipped {' and '.join(what)}" + (f" ({', '.join(held)})" if held else "")

    def _messages_lost(self) -> str:
        """Exact from a finished file's count; else from the indexes after the chunks."""
        if self.expected is not None:
            lost = self.expected - self.read
            return f"{lost:,} message{'s' * (lost != 1)}"
        counts = [loss.messages for loss in self.losses]
        lost = sum(count or 0 for count in counts)
        if None not in counts:
            return f"{lost:,} message{'s' * (lost != 1)}"
        return f"at least {lost:,} messages" if lost else "how many messages is not known"


def _when(stamp: int) -> str:
    """A log_time (ns) to the millisecond, UTC, as every time is shown."""
    return at(stamp)


def _latest(one: int | None, other: int | None) -> int | None:
    return max((t for t in (one, other) if t is not None), default=None)


def _after(stamp: int | None) -> str:
    return "before any message" if stamp is None else f"after {_when(stamp)}"


def _span(after: int | None, before: int | None) -> str:
    """When nothing was read: between the messages read around a loss."""
    if after is None and before is None:
        return ""
    if before is None:
        return f"nothing {_after(after)}"
    if after is None:
        return f"nothing before {_when(before)}"
    start, end = _when(after), _when(before)
    if start[:11] == end[:11]:
        end = end[11:]
    return f"nothing from {start} to {end}, {(before - after) / 1e9:.3f} s"


class Reading:
    """What reading a set of files met: a report per file, in the order read."""

    def __init__(self, on_file: Callable[[FileReport], None] | None = None) -> None:
        self.files: list[FileReport] = []
        self._on_file = on_file

    @property
    def partial(self) -> bool:
        return any(report.partial for report in self.files)

    def lines(self) -> list[str]:
        """One line for each file not read whole, however often it was read (issue 43:
        an export of two trials said a file being written twice)."""
        joined: dict[Path, FileReport] = {}
        for report in self.files:
            kept = joined.get(report.path)
            joined[report.path] = report if kept is None else kept.joined(report)
        return [line for report in joined.values() if (line := report.line())]

    def done(self, report: FileReport) -> None:
        if self._on_file is not None:
            self._on_file(report)
