"""Reading recordings back, past any damage: the messages of one file or several, in
the order written, and a report of what could not be read (:mod:`.reports`)."""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import IO

import zstandard
from mcap.opcode import Opcode

from .blocks import Block, Span, entries_of, one, parsed
from .entry import Entry
from .files import (
    CHUNK_HEAD,
    FOOTER_BYTES,
    LARGEST_CHUNK,
    MAGIC,
    MESSAGE_HEAD,
    RECORD_HEAD,
    SCAN_BYTES,
    being_written,
    known_opcode,
    unreadable,
)
from .index import ChunkSpan, FileIndex, channel_of, parse
from .reports import FileReport, Loss, Reading

# --- reading --------------------------------------------------------------------------------
#
# Files are read record by record (the MCAP spec's framing: an opcode byte, a u64 length,
# the body), not through the mcap package's readers: those stop at the first thing they
# cannot parse, and a file damaged in the middle (a bad sector, a copy cut and resumed)
# would lose everything after it. Here a chunk that does not decompress or fails its CRC
# is skipped by its length, and the walk goes on at the next record; where the framing
# itself is broken (no record starts where the last one ended), the walk scans forward
# for the next chunk whose header is consistent (its lengths add up to its record's)
# and whose content passes its CRC. A file is read front to back, so one whose writer
# was killed reads up to its last whole chunk; its summary (a finished file's channels
# and message count) is read first, when there is one, so that a damaged chunk that
# held a channel's definition loses no later message and the messages lost are counted
# exactly. The messages are handed out a chunk at a time (:class:`.blocks.Block`), and
# one at a time from those (:func:`read`).


def read(path: Path, reading: Reading, topics: Iterable[str] | None = None,
         span: Span | None = None) -> Iterator[Entry]:
    """The messages of one file, in the order written, past any damage; what was
    skipped (the whole file, or stretches of it) goes in a report added to ``reading``.
    With ``topics`` or ``span``, only the messages on those topics and logged in that
    span, and only the chunks that can hold them decompressed (a finished file's
    chunk index says where they are; in another, each chunk's header says its span)."""
    return entries_of(read_blocks(path, reading, topics, span))


def read_all(paths: Iterable[Path], reading: Reading,
             topics: Iterable[str] | None = None, span: Span | None = None
             ) -> Iterator[Entry]:
    for path in paths:
        yield from read(path, reading, topics, span)


def read_blocks(path: Path, reading: Reading, topics: Iterable[str] | None = None,
                span: Span | None = None) -> Iterator[Block]:
    """:func:`read`'s messages a chunk at a time (none empty)."""
    report = FileReport(path)
    reading.files.append(report)
    report.skipped = unreadable(path)
    if not report.skipped:
        wanted = None if topics is None else frozenset(topics)
        try:
            with path.open("rb") as stream:
                yield from _Walk(stream, report, span).blocks(wanted)
        except OSError as error:  # the disk failing under the reader
            report.skipped = (f"reading failed after {report.read:,} messages: "
                              f"{error.strerror or error}")
        report.writing = not report.whole and being_written(path)
    reading.done(report)


def read_all_blocks(paths: Iterable[Path], reading: Reading,
                    topics: Iterable[str] | None = None, span: Span | None = None
                    ) -> Iterator[Block]:
    for path in paths:
        yield from read_blocks(path, reading, topics, span)


def index_of(path: Path) -> tuple[FileIndex | None, FileReport]:
    """A finished file's summary, if it has a whole one (None otherwise), and the
    report of looking (its ``summary`` says what was wrong with a damaged one)."""
    report = FileReport(path)
    report.skipped = unreadable(path)
    if report.skipped:
        return None, report
    try:
        with path.open("rb") as stream:
            walk = _Walk(stream, report)
            walk.find_summary()
            return walk.index, report
    except OSError as error:
        report.skipped = str(error.strerror or error)
        return None, report


class _Walk:
    """One MCAP file read record by record, skipping what cannot be read."""

    def __init__(self, stream: IO[bytes], report: FileReport, span: Span | None = None
                 ) -> None:
        self._stream = stream
        self._report = report
        self._span = span
        self._size = os.fstat(stream.fileno()).st_size
        self._channels: dict[int, str] = {}
        self.index: FileIndex | None = None
        """The file's summary, where it has a whole one."""
        self._waiting: list[Loss] = []
        """Losses waiting for the next message read: when they ended."""
        self._counting: Loss | None = None
        """A damaged chunk, whose message index (after it) counts its messages."""
        self._passed: tuple[int, int] | None = None
        """A chunk passed over unread (outside the span): (offset, length) of its body,
        decompressed after all if its message index names a channel not yet defined
        (a file without summary defines each channel in the chunk that first uses it)."""
        self._deferred: tuple[int, int, bool] | None = None
        """A chunk waiting for its message indexes to say whether it is read: its
        offset, its end, and whether an index has named a channel (none wanted)."""
        self._unindexed: list[tuple[int, int]] = []
        """The chunks passed over whose channels no message index told (another
        writer's file may have none): decompressed for their channels when a message
        on a channel not yet defined is met."""

    def _at(self, offset: int, size: int) -> bytes:
        self._stream.seek(offset)
        return self._stream.read(size)

    def find_summary(self) -> int:
        """Where the data section ends (the summary read, if whole, into ``index``)."""
        return self._summary()

    def blocks(self, wanted: frozenset[str] | None) -> Iterator[Block]:
        damaged = False  # (a skipped stretch before messages not wanted: said by the next)
        for block in self._blocks(wanted):
            damaged = damaged or block.after_damage
            block = block.kept(self._span, None if wanted is None else block.on(
                wanted.__contains__))
            if len(block):
                yield block.marked(damaged)
                damaged = False

    def _blocks(self, wanted: frozenset[str] | None) -> Iterator[Block]:
        end = self._summary()
        if self.index is not None and self.index.chunks and (
                self._span is not None or wanted is not None):
            # only some of the file wanted: its chunk index says which chunks, and the
            # message count cannot tell what damage lost any more (read less than it)
            self._report.expected = None
            yield from self._indexed(end, wanted)
            return
        at = len(MAGIC)
        while at < end:
            head = self._at(at, RECORD_HEAD.size)
            opcode, length = RECORD_HEAD.unpack(head) if len(head) == RECORD_HEAD.size \
                else (0, 0)
            after = at + RECORD_HEAD.size + length
            if self._deferred is not None:  # (its message indexes follow it)
                yield from self._undefer(at, after, end, opcode, wanted)
            if not known_opcode(opcode) or after > end:
                at = self._resync(at, end, chunk=opcode == Opcode.CHUNK)
                continue
            if opcode == Opcode.DATA_END:
                self._report.whole = True
                break
            if opcode == Opcode.CHUNK and not self._touches(at):
                self._counting = None
                self._passed = (at + RECORD_HEAD.size, length)
                self._unindexed.append(self._passed)
                at = after  # outside the span: passed over without reading it
                continue
            if opcode == Opcode.CHUNK and wanted is not None:
                self._counting = self._passed = None
                self._deferred = (at, after, False)  # (read if its indexes ask)
                at = after
                continue
            if opcode == Opcode.CHUNK:
                self._passed = None
                found = self._chunk(self._at(at + RECORD_HEAD.size, length))
                if found is None:
                    at = self._damaged_chunk(at, after, end)
                    continue
                self._counting = None
                block = self._block(found)
                if block is not None:
                    yield block
            elif opcode in (Opcode.MESSAGE, Opcode.CHANNEL, Opcode.MESSAGE_INDEX):
                body = self._at(at + RECORD_HEAD.size, length)
                try:
                    block = self._top_level(opcode, body)
                except (struct.error, UnicodeDecodeError):
                    at = self._resync(at, end, chunk=False)
                    continue
                if block is not None:
                    yield block
            at = after
        if self._deferred is not None:
            yield from self._undefer(at, at, end, None, wanted)
        if at >= end and end < self._size:
            self._report.whole = True  # at the summary of a finished file

    # In a file without summary, only some topics wanted (a file being written, read for
    # its marks: issue 43), a chunk waits for the message indexes written after it, one
    # a channel: it is read when one names a wanted channel or one not yet defined (its
    # topic is in the chunk), or when none follows it (another writer's file may have
    # none); a chunk whose indexes name only other channels is passed over unread, once a
    # whole record of a known kind after them shows their list complete.

    def _undefer(self, at: int, after: int, end: int, opcode: int | None,
                 wanted: frozenset[str] | None) -> Iterator[Block]:
        """The chunk waiting for its message indexes, given the record at ``at``: read
        (its wanted messages yielded), passed over, or still waiting."""
        assert self._deferred is not None
        chunk, chunk_end, indexed = self._deferred
        if opcode == Opcode.MESSAGE_INDEX and after <= end:
            channel = self._at(at + RECORD_HEAD.size, 2)
            topic = self._channels.get(int.from_bytes(channel, "little"))
            if len(channel) == 2 and topic is not None and topic not in (wanted or ()):
                self._deferred = (chunk, chunk_end, True)
                return
        elif indexed and opcode is not None and known_opcode(opcode) and after <= end:
            # its indexes named none wanted, and their list is whole (a record whole and
            # known follows it): passed over unread. At the end of the data, or before a
            # record cut short or unknown, the list may be cut short (a writer killed
            # while it flushed: the wanted channel's index never written): read it.
            self._deferred = None
            head = self._at(chunk + RECORD_HEAD.size, 16)
            if len(head) == 16:
                self._pass_over(*struct.unpack("<QQ", head))
            return
        self._deferred = None
        found = self._chunk(self._at(chunk + RECORD_HEAD.size, chunk_end - chunk
                                     - RECORD_HEAD.size))
        if found is None:  # (its messages not counted: its indexes were passed over)
            self._lost(chunk, chunk_end - chunk, chunk=True)
            return
        block = self._block(found)
        if block is not None:
            yield block

    def _touches(self, at: int) -> bool:
        """Whether the chunk at ``at`` can hold messages of the span, by its header."""
        if self._span is None:
            return True
        head = self._at(at + RECORD_HEAD.size, 16)
        if len(head) < 16:
            return True  # (the walk finds out what is wrong with it)
        start, stop = struct.unpack("<QQ", head)
        if stop >= self._span[0] and start < self._span[1]:
            return True
        self._pass_over(start, stop)
        return False

    def _pass_over(self, start: int, stop: int) -> None:
        """A chunk of messages logged from ``start`` to ``stop`` passed over unread."""
        if start <= stop:  # (what the file holds past it, for where it ends)
            self._report.passed = max(stop, self._report.passed or 0)
            for loss in self._waiting:  # a loss ends where a chunk passed over starts
                loss.before = start
            self._waiting.clear()

    def _indexed(self, end: int, wanted: frozenset[str] | None) -> Iterator[Block]:
        """The messages of the chunks the index says can hold wanted ones, each
        sought directly; one that is not where the index says, or does not read, lost."""
        assert self.index is not None
        ids = None if wanted is None else frozenset(
            channel for channel, topic in self.index.channels.items() if topic in wanted)
        for chunk in self.index.chunks:
            if not chunk.touches(self._span) or (ids is not None and not chunk.holds(ids)):
                continue
            head = self._at(chunk.offset, RECORD_HEAD.size)
            length = chunk.length - RECORD_HEAD.size
            found = None
            if (len(head) == RECORD_HEAD.size and RECORD_HEAD.unpack(head) == (
                    Opcode.CHUNK, length) and chunk.offset + chunk.length <= end):
                found = self._chunk(self._at(chunk.offset + RECORD_HEAD.size, length))
            if found is None:
                loss = self._lost(chunk.offset, chunk.length, chunk=True)
                loss.messages = self._indexed_count(chunk, ids)
                continue
            block = self._block(found.kept(self._span, ids))
            if block is not None:
                yield block
        self._report.whole = True

    def _indexed_count(self, chunk: ChunkSpan, ids: frozenset[int] | None) -> int | None:
        """The messages a damaged chunk held in the span (of the wanted channels), from
        its message indexes (written after it, each a log_time and an offset per
        message); None if one of them does not read."""
        low, high = self._span or (0, 2 ** 64)
        count = 0
        for channel, offset in _INDEX_OFFSET.iter_unpack(chunk.offsets):
            if ids is not None and channel not in ids:
                continue
            head = self._at(offset, _INDEX_HEAD.size)
            if len(head) < _INDEX_HEAD.size:
                return None
            opcode, length, indexed, width = _INDEX_HEAD.unpack(head)
            if opcode != Opcode.MESSAGE_INDEX or indexed != channel or width + 6 != length:
                return None
            entries = self._at(offset + _INDEX_HEAD.size, width)
            if len(entries) != width or width % 16:
                return None
            count += sum(low <= log_time < high
                         for log_time, _ in struct.iter_unpack("<QQ", entries))
        return count

    # The footer's summary start is only a hint: a flipped bit or a stray write there
    # would otherwise end the data section wherever it points, and every chunk after
    # that would go unread without a word. It is used where it checks out (a data end
    # record just before it, and the summary's records tiling exactly up to the
    # footer); else the data section's end is found from the records themselves (each
    # record's opcode and length lead to the next, up to the data end), and the
    # summary is looked for there. The damage is said (FileReport.summary).

    def _summary(self) -> int:
        """Where the data section ends: a finished file's summary (its channels and
        message count read here), else the end of the file, or its footer's start."""
        if self._size < len(MAGIC) + FOOTER_BYTES:
            return self._size
        tail = self._at(self._size - FOOTER_BYTES, FOOTER_BYTES)
        opcode, length = RECORD_HEAD.unpack_from(tail)
        if tail[-len(MAGIC):] != MAGIC or opcode != Opcode.FOOTER or length != 20:
            return self._size
        footer = self._size - FOOTER_BYTES
        (start,) = struct.unpack_from("<Q", tail, RECORD_HEAD.size)
        if start == 0:
            return footer  # no summary written (as the MCAP spec allows)
        if self._summary_at(start, footer):
            return start
        found = self._data_end(footer)
        if found is not None and self._summary_at(found, footer):
            self._report.summary = ("its footer is damaged (it points to the wrong place "
                                    "for the summary, found by reading the records)")
            return found
        self._report.summary = "its summary is damaged (not used)"
        return footer

    def _summary_at(self, start: int, footer: int) -> bool:
        """Whether a summary starts at ``start``: after a data end record, its records
        tiling exactly up to the footer; its channels and message count read if so."""
        if not len(MAGIC) + _DATA_END_BYTES <= start <= footer:
            return False
        before = self._at(start - _DATA_END_BYTES, RECORD_HEAD.size)
        if RECORD_HEAD.unpack(before) != (Opcode.DATA_END, _DATA_END_BYTES - RECORD_HEAD.size):
            return False
        summary = self._at(start, footer - start)
        at = 0
        try:
            while at < len(summary):
                opcode, length = RECORD_HEAD.unpack_from(summary, at)
                if not known_opcode(opcode):
                    return False
                at += RECORD_HEAD.size + length
            index = parse(summary)
        except (struct.error, UnicodeDecodeError):
            return False
        self._channels.update(index.channels)
        self._report.expected = index.messages
        self.index = index
        return True

    def _data_end(self, footer: int) -> int | None:
        """Where the data section ends, by its records' lengths (one read of each
        record's head); None if they do not lead to a data end record."""
        at = len(MAGIC)
        while at + RECORD_HEAD.size <= footer:
            opcode, length = RECORD_HEAD.unpack(self._at(at, RECORD_HEAD.size))
            at += RECORD_HEAD.size + length
            if not known_opcode(opcode) or at > footer:
                return None
            if opcode == Opcode.DATA_END:
                return at
        return None

    def _chunk(self, body: bytes) -> Block | None:
        """A chunk's messages (their topics not yet set), its channels registered; None
        if the chunk is damaged (nothing of it is used then)."""
        try:
            _, _, size, crc, width = CHUNK_HEAD.unpack_from(body)
            compression = body[CHUNK_HEAD.size:CHUNK_HEAD.size + width].decode()
            (stored,) = struct.unpack_from("<Q", body, CHUNK_HEAD.size + width)
            data = body[CHUNK_HEAD.size + width + 8:]
            if len(data) != stored:
                return None
            if size > LARGEST_CHUNK:
                return None
            self._report.decompressed += 1
            records = _decompress(compression, data, size)
            if len(records) != size or (crc and zlib.crc32(records) != crc):
                return None
            found, channels = parsed(records)
        # a damaged chunk fails in whatever decodes it (a struct, the decompressor, a
        # name's UTF-8): every one of them means the same, the chunk is skipped
        except Exception:
            return None
        self._channels.update(channels)
        return found

    def _top_level(self, opcode: int, body: bytes) -> Block | None:
        """A record outside chunks: a message (an unchunked file), a channel, or the
        message index of the chunk before it."""
        if opcode == Opcode.CHANNEL:
            channel, topic = channel_of(body)
            self._channels[channel] = topic
        elif opcode == Opcode.MESSAGE_INDEX:
            channel, width = struct.unpack_from("<HI", body)
            if self._unindexed and self._unindexed[-1] == self._passed:
                self._unindexed.pop()  # (its message indexes tell its channels)
            if self._passed is not None and channel not in self._channels:
                self._chunk(self._at(*self._passed))  # for its channels only
                self._passed = None
            if self._counting is not None:
                self._counting.messages = (self._counting.messages or 0) + width // 16
        else:
            channel, _, log_time, publish_time = MESSAGE_HEAD.unpack_from(body)
            return self._block(one(channel, log_time, publish_time, body[MESSAGE_HEAD.size:]))
        return None

    def _block(self, found: Block) -> Block | None:
        """A chunk's messages (those a read keeps) with their topics, counted read; those
        on a channel not defined (its definition was lost with a damaged chunk) counted
        as orphans and left out; None if none is left."""
        present = set(found.channel)
        topics = {channel: self._channels.get(channel) for channel in present}
        if None in topics.values() and self._unindexed:
            for passed in self._unindexed:
                self._chunk(self._at(*passed))  # for its channels only
            self._unindexed.clear()
            topics = {channel: self._channels.get(channel) for channel in present}
        if None in topics.values():
            known = [i for i, channel in enumerate(found.channel) if topics[channel] is not None]
            self._report.orphans += len(found) - len(known)
            found = found.taken(known)
        if not len(found):
            return None
        self._report.read += len(found)
        self._report.last = found.log_time[-1]
        for loss in self._waiting:
            loss.before = found.log_time[0]
        damaged = bool(self._waiting)
        self._waiting.clear()
        return replace(found, topics={channel: topic for channel, topic in topics.items()
                                      if topic is not None}, after_damage=damaged)

    def _lost(self, offset: int, size: int, chunk: bool) -> Loss:
        after = max((t for t in (self._report.last, self._report.passed) if t is not None),
                    default=None)  # (the chunks passed over held messages up to there)
        loss = Loss(offset, size, chunk, after=after)
        self._report.losses.append(loss)
        self._waiting.append(loss)
        return loss

    def _damaged_chunk(self, at: int, after: int, end: int) -> int:
        """Where to go on after a chunk that cannot be read: the next record if its
        length led to one (only its content is damaged), else the next chunk found."""
        if after == end or self._plausible(after, end):
            self._counting = self._lost(at, after - at, chunk=True)
            return after
        return self._resync(at, end, chunk=True)

    def _plausible(self, at: int, end: int) -> bool:
        head = self._at(at, RECORD_HEAD.size)
        if len(head) < RECORD_HEAD.size:
            return False
        opcode, length = RECORD_HEAD.unpack(head)
        return known_opcode(opcode) and at + RECORD_HEAD.size + length <= end

    def _resync(self, at: int, end: int, chunk: bool) -> int:
        """The next chunk after ``at`` that reads, the stretch before it lost; none in a
        file cut short: the rest is its unfinished tail, not damage (its writer died
        writing it); none in a finished file: the rest is lost."""
        found = self._next_chunk(at + 1, end)
        if found is None and end == self._size:
            return end
        stop = end if found is None else found
        self._counting = None
        self._lost(at, stop - at, chunk)
        return stop

    def _next_chunk(self, start: int, end: int) -> int | None:
        """The offset of the next chunk record at or after ``start`` whose header is
        consistent and whose content reads (its CRC holds)."""
        offset = start
        while offset < end:
            block = self._at(offset, min(SCAN_BYTES, end - offset))
            at = block.find(bytes((Opcode.CHUNK,)))
            while at >= 0:
                if self._is_chunk(offset + at, end):
                    return offset + at
                at = block.find(bytes((Opcode.CHUNK,)), at + 1)
            offset += len(block)
            if not block:
                break
        return None

    def _is_chunk(self, at: int, end: int) -> bool:
        head = self._at(at, RECORD_HEAD.size + CHUNK_HEAD.size)
        if len(head) < RECORD_HEAD.size + CHUNK_HEAD.size:
            return False
        _, length = RECORD_HEAD.unpack_from(head)
        start, stop, _, _, width = CHUNK_HEAD.unpack_from(head, RECORD_HEAD.size)
        if width > 16 or start > stop or at + RECORD_HEAD.size + length > end:
            return False
        body_at = at + RECORD_HEAD.size
        stored = self._at(body_at + CHUNK_HEAD.size + width, 8)
        if len(stored) < 8 or struct.unpack("<Q", stored)[0] != (
                length - CHUNK_HEAD.size - width - 8):
            return False
        # (read twice when it is the one: a chunk found this way is rare)
        return self._chunk(self._at(body_at, length)) is not None


_INDEX_OFFSET = struct.Struct("<HQ")
"""A chunk index's entry: a channel, and where that channel's message index is."""
_INDEX_HEAD = struct.Struct("<BQHI")
"""A message index record's head: opcode, length, channel, its entries' byte length."""
_DATA_END_BYTES = RECORD_HEAD.size + 4
"""A data end record: its head and a CRC."""


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(data)
    if compression == "":
        return data
    raise ValueError(f"unknown compression {compression!r}")
