"""A finished recording's summary, parsed: its channels, its statistics (the span and
message counts of the whole file and of each channel) and its chunk indexes (where
each chunk is, the span of its messages and the channels it holds). It is what lets
the catalogue describe a file without reading its messages, and a window read seek
to the chunks it needs (:mod:`.reader` checks the summary is whole before using it)."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from mcap.opcode import Opcode

from .files import LARGEST_CHUNK, MAGIC, MESSAGE_HEAD, RECORD_HEAD, known_opcode

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_ID_COUNT = struct.Struct("<HQ")
"""An entry of a map from a channel id (u16) to a u64: counts, offsets."""
_STATISTICS = struct.Struct("<QHIIIIQQ")
_CHUNK_INDEX = struct.Struct("<QQQQI")
"""A chunk index's head: its times, offset and length, and its offsets' byte length."""


class ChunkSpan(NamedTuple):
    """One chunk as its index gives it (a tuple: a day of files has 86,400 of them)."""

    start: int
    """log_time (ns) of its first message, and of its last."""
    end: int
    offset: int
    """Where its record starts in the file, and the record's whole length."""
    length: int
    offsets: bytes
    """Its message indexes' offsets, by channel id (as the file has them: parsed only
    when asked which channels it holds)."""

    def touches(self, span: tuple[int, int] | None) -> bool:
        """Whether any of its messages can be in ``span`` (ns, end excluded)."""
        return span is None or (self.end >= span[0] and self.start < span[1])

    def holds(self, channels: frozenset[int]) -> bool:
        """Whether it holds messages of any of ``channels``."""
        return any(channel in channels for channel, _ in _ID_COUNT.iter_unpack(self.offsets))


@dataclass
class FileIndex:
    """What a finished file's summary says of it."""

    channels: dict[int, str] = field(default_factory=dict)
    messages: int | None = None
    """The file's message count (None: no statistics record)."""
    start: int | None = None
    """log_time (ns) of the file's first message, and of its last."""
    end: int | None = None
    counts: dict[int, int] = field(default_factory=dict)
    """Messages per channel id."""
    chunks: list[ChunkSpan] = field(default_factory=list)

    def topic_counts(self) -> dict[str, int]:
        """Messages per topic (a topic on two channels adds them up)."""
        found: dict[str, int] = {}
        for channel, count in self.counts.items():
            topic = self.channels.get(channel)
            if topic is not None:
                found[topic] = found.get(topic, 0) + count
        return found


def _map(body: bytes, at: int) -> tuple[dict[int, int], int]:
    """A map of u16 to u64 at ``at`` (its byte length first); and where it ends."""
    (width,) = _U32.unpack_from(body, at)
    at += _U32.size
    end = at + width
    if end > len(body):
        raise struct.error("a map runs past its record")
    found = {}
    while at < end:
        key, value = _ID_COUNT.unpack_from(body, at)
        found[key] = value
        at += _ID_COUNT.size
    return found, end


def channel_of(body: bytes) -> tuple[int, str]:
    """(id, topic) of a channel record's body."""
    channel, _, width = struct.unpack_from("<HHI", body)
    topic = body[8:8 + width]
    if len(topic) != width:
        raise struct.error("a channel's topic runs past its record")
    return channel, topic.decode()


def parse(summary: bytes) -> FileIndex:
    """The index of a summary section's records (struct.error or UnicodeDecodeError if
    they do not parse); records of other kinds are passed over."""
    index = FileIndex()
    at = 0
    while at < len(summary):
        opcode, length = RECORD_HEAD.unpack_from(summary, at)
        body = summary[at + RECORD_HEAD.size:at + RECORD_HEAD.size + length]
        if len(body) != length:
            raise struct.error("a summary record runs past the summary")
        if opcode == Opcode.CHANNEL:
            channel, topic = channel_of(body)
            index.channels[channel] = topic
        elif opcode == Opcode.STATISTICS:
            (index.messages, _, _, _, _, _, start, end) = _STATISTICS.unpack_from(body)
            if index.messages:
                index.start, index.end = start, end
            index.counts, _ = _map(body, _STATISTICS.size)
        elif opcode == Opcode.CHUNK_INDEX:
            start, end, offset, chunk_length, width = _CHUNK_INDEX.unpack_from(body)
            offsets = body[_CHUNK_INDEX.size:_CHUNK_INDEX.size + width]
            if len(offsets) != width or width % _ID_COUNT.size:
                raise struct.error("a chunk index's offsets run past it")
            index.chunks.append(ChunkSpan(start, end, offset, chunk_length, offsets))
        at += RECORD_HEAD.size + length
    index.chunks.sort(key=lambda chunk: chunk.offset)
    if index.messages is None and index.chunks:
        # no statistics record (another writer's choice): the span is the chunks'
        index.start = min(chunk.start for chunk in index.chunks)
        index.end = max(chunk.end for chunk in index.chunks)
    return index


class Walked(NamedTuple):
    """What the records' heads of a file without summary say of it."""

    span: tuple[int, int] | None
    """(first, last) log_time (ns); None if no message was met."""
    whole: bool
    """The records tile the file up to its end (or a data end): the span is all of
    it. False where the framing breaks before: a reader scanning past it may find
    later messages, so the span is only the part before."""


def walked_span(path: Path) -> Walked:
    """The span of a file without summary, from its chunks' headers (and its
    unchunked messages' heads): nothing decompressed."""
    first = last = None
    size = path.stat().st_size
    whole = False
    with path.open("rb") as stream:
        at = stream.seek(len(MAGIC))
        while True:
            head = stream.read(RECORD_HEAD.size)
            if len(head) < RECORD_HEAD.size:
                # the end of the file, or a record's head cut by it (a writer killed)
                whole = True
                break
            opcode, length = RECORD_HEAD.unpack(head)
            if opcode == Opcode.DATA_END:
                whole = True
                break
            at += RECORD_HEAD.size + length
            if not known_opcode(opcode) or at > size:
                # framing broken, or a record cut by the file's end: whole only for
                # a chunk of a plausible length (a killed writer's last, cut writing)
                whole = opcode == Opcode.CHUNK and length <= LARGEST_CHUNK and at > size
                break
            if opcode in (Opcode.CHUNK, Opcode.MESSAGE):
                body = stream.read(min(length, MESSAGE_HEAD.size))
                if len(body) < MESSAGE_HEAD.size:
                    break
                if opcode == Opcode.CHUNK:
                    start, end = struct.unpack_from("<QQ", body)
                else:
                    start = end = MESSAGE_HEAD.unpack_from(body)[2]
                if start <= end and (start or end):
                    first = start if first is None else min(first, start)
                    last = end if last is None else max(last, end)
                stream.seek(length - len(body), 1)
            else:
                stream.seek(length, 1)
    return Walked(None if first is None or last is None else (first, last), whole)
