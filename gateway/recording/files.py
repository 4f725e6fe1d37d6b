"""Recordings on disk: MCAP files, what their channels hold, and reading them back.

A recording is readable by any MCAP reader (Foxglove, PlotJuggler, the ``mcap``
package); this module is the one place that knows its channels:

- ``serial``: every read from the base station, the bytes exactly as read;
  ``log_time`` the read's UNIX time, ``publish_time`` its time on the host's monotonic
  clock (both ns), so a replay feeds the clock estimate the very pairs it saw live;
- ``serial/written``: every write to the base station, stamped the same way, so a
  capture shows both directions of the line;
- ``gx2/<address>/<record>``, ``gx2/gateway/status`` and ``gx2/gateway/mark``: each
  published message as one JSON object (NaN as null); ``log_time`` its ``host_time``
  (for a status, its ``gateway.time``), ``publish_time`` its ``time`` where it has one.

Files are written in the order things happened, so reading a file front to back (which
also works on a file whose writer was killed before it finished) gives them in order.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import struct
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import zstandard
from mcap.opcode import Opcode
from mcap.writer import CompressionType, Writer

from gateway.common.jsontext import compact
from gateway.common.schemas import ENCODING as SCHEMA_ENCODING
from gateway.common.schemas import schema_for_topic
from gateway.common.topics import MARK_TOPIC
from gateway.common.version import VERSION

SERIAL = "serial"
WRITTEN = "serial/written"
RAW_ENCODING = "octets"
"""The serial channels' message encoding: the bytes themselves, no schema."""
JSON_ENCODING = "json"
SUFFIX = ".mcap"
PROFILE = "gx2"
CHUNK_BYTES = 1 << 20
"""A chunk is closed at this size, or when the writer is flushed (once a second)."""


class RecordingError(Exception):
    """A recording cannot be read (missing, not MCAP): one line for the user."""


def file_name(now: float | None = None) -> str:
    """``gx2-20261122T101530.482Z.mcap``: UTC, fixed width, so names sort in time order."""
    stamp = time.time() if now is None else now
    seconds = time.strftime("%Y%m%dT%H%M%S", time.gmtime(stamp))
    return f"gx2-{seconds}.{int(stamp % 1 * 1000):03d}Z{SUFFIX}"


def ns(seconds: float) -> int:
    return round(seconds * 1e9)


class RecordingWriter:
    """One MCAP file being written: channels registered as they first appear."""

    def __init__(self, output: IO[bytes], metadata: Mapping[str, str] | None = None) -> None:
        self._output = output
        self._writer = Writer(output, chunk_size=CHUNK_BYTES,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"gx2-gateway {VERSION}")
        if metadata:
            self._writer.add_metadata("gx2-gateway", dict(metadata))
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.messages = 0
        self.kept = 0
        """Messages handed to the OS by the last flush: what a failed disk leaves."""
        self._kept_at = 0

    def _channel(self, topic: str, encoding: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schema(topic) if encoding == JSON_ENCODING else 0
            channel = self._channels[topic] = self._writer.register_channel(
                topic, encoding, schema_id=schema)
        return channel

    def _schema(self, topic: str) -> int:
        """The id of the JSON Schema of what is published on ``topic``, written into the
        file the first time a channel needs it (0, no schema, for a topic the gateway
        does not publish). PlotJuggler skips a channel without a schema; the serial
        channels' raw bytes have none, as MCAP allows."""
        found = schema_for_topic(topic)
        if found is None:
            return 0
        name, schema = found
        schema_id = self._schemas.get(name)
        if schema_id is None:
            schema_id = self._schemas[name] = self._writer.register_schema(
                name, SCHEMA_ENCODING, compact(schema).encode())
        return schema_id

    def serial(self, data: bytes, host_time: float, monotonic: float,
               topic: str = SERIAL) -> None:
        """A read from (or, with ``topic=WRITTEN``, a write to) the base station."""
        self.messages += 1
        self._writer.add_message(self._channel(topic, RAW_ENCODING), ns(host_time), data,
                                 ns(monotonic), self.messages)

    def message(self, topic: str, payload: Mapping[str, Any]) -> None:
        """A published message: a node's record, or the gateway's status."""
        logged = payload.get("host_time")
        if logged is None:
            gateway = payload.get("gateway")
            logged = gateway.get("time") if isinstance(gateway, Mapping) else None
        if not isinstance(logged, (int, float)) or not math.isfinite(logged):
            logged = time.time()
        sampled = payload.get("time")
        if not isinstance(sampled, (int, float)) or not math.isfinite(sampled):
            sampled = logged
        self.messages += 1
        self._writer.add_message(self._channel(topic, JSON_ENCODING), ns(logged),
                                 compact(payload).encode(), ns(sampled), self.messages)

    def flush(self) -> None:
        """Close the chunk in progress and hand it to the OS: what a process killed
        from now on leaves readable."""
        self._writer.flush()
        self.kept = self.messages
        self._kept_at = self._output.tell()

    def abandon(self, path: Path) -> None:
        """After a write failed (a full disk): the file ``path`` cut back to its last
        flush and ended there (a data end and a footer without summary, as the MCAP
        spec allows), so a reader reads what it keeps whole; a file that keeps no
        message is removed. If the disk refuses even that, what it has stays readable
        up to its last whole chunk."""
        with contextlib.suppress(OSError, ValueError):
            self._output.close()
        with contextlib.suppress(OSError):
            if not self.kept:
                path.unlink()
                return
            os.truncate(path, self._kept_at)
            with path.open("ab") as output:
                output.write(_END)

    def finish(self) -> None:
        """Write the summary and index, make sure the disk has it all, close the file."""
        self._writer.finish()
        self._output.flush()
        with contextlib.suppress(OSError, AttributeError, io.UnsupportedOperation):
            os.fsync(self._output.fileno())
        self._output.close()


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
# exactly.

MAGIC = b"\x89MCAP0\r\n"
MARK = MARK_TOPIC.decode()
"""The channel of marks (``gx2ctl mark``), each a JSON object (see MARK_TOPIC)."""
PARTIAL = 1
"""Exit status of export, plot, and a replay with ``exit=true``, that skipped something
unreadable (a file, a damaged chunk) and read the rest."""
_RECORD_HEAD = struct.Struct("<BQ")
_END = (_RECORD_HEAD.pack(Opcode.DATA_END, 4) + bytes(4)
        + _RECORD_HEAD.pack(Opcode.FOOTER, 20) + bytes(20) + MAGIC)
"""A data end (no CRC) and a footer saying there is no summary: a file's end."""
_MESSAGE_HEAD = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
_FOOTER_BYTES = _RECORD_HEAD.size + 20 + len(MAGIC)
_PRIVATE_OPCODES = 0x80
"""Opcodes from here on are for any writer's own records, skipped by their length."""
_SCAN_BYTES = 1 << 20
_LARGEST_CHUNK = 1 << 30
"""A chunk said to be larger is damaged (ours close at CHUNK_BYTES): not decompressed."""


@dataclass(frozen=True)
class Entry:
    """One message of a recording."""

    topic: str
    log_time: int
    publish_time: int
    data: bytes

    def payload(self) -> dict[str, Any]:
        """A JSON channel's message; RecordingError if it is not a JSON object."""
        try:
            value = json.loads(self.data)
        except ValueError:
            raise RecordingError(f"a message on {self.topic} is not JSON") from None
        if not isinstance(value, dict):
            raise RecordingError(f"a message on {self.topic} is not a JSON object")
        return value


@dataclass(frozen=True)
class Mark:
    """A mark (``gx2ctl mark``): what happened, when (UNIX s), to which nodes."""

    time: float
    host_time: float
    nodes: tuple[int, ...]
    text: str

    @classmethod
    def of(cls, entry: Entry) -> Mark:
        """The mark an entry on MARK holds, its recorded times standing in for a
        missing or non-numeric ``time`` or ``host_time``."""
        payload = entry.payload()
        host_time = _seconds(payload.get("host_time"), entry.log_time / 1e9)
        nodes = payload.get("nodes")
        return cls(_seconds(payload.get("time"), entry.publish_time / 1e9), host_time,
                   tuple(n for n in nodes if isinstance(n, int) and not isinstance(n, bool))
                   if isinstance(nodes, list) else (), str(payload.get("text") or ""))

    def concerns(self, node: int) -> bool:
        """A mark of the whole experiment, or one naming ``node``."""
        return not self.nodes or node in self.nodes


def _seconds(value: Any, default: float) -> float:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return default


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

    @property
    def partial(self) -> bool:
        """Something in it could not be read (a file cut short is not, by itself)."""
        return bool(self.skipped or self.losses or self.orphans)

    def line(self) -> str:
        """One line for the user; empty for a file read whole."""
        if self.skipped:
            return f"{self.path}: skipped: {self.skipped}"
        said = []
        if self.losses or self.orphans:
            said.append(self._damage())
        if not self.whole:
            said.append(f"ends early {_after(self.last)} (its writer was stopped without "
                        "warning)")
        if not said:
            return ""
        return f"{self.path}: {'; '.join(said)}; read " + (
            "the rest" if self.losses or self.orphans else "up to there")

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
    """A log_time (ns) to the nearest millisecond, UTC."""
    seconds, milliseconds = divmod((stamp + 500_000) // 1_000_000, 1000)
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(seconds)) + f".{milliseconds:03d} UTC"


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
        """One line for each file not read whole."""
        return [line for report in self.files if (line := report.line())]

    def done(self, report: FileReport) -> None:
        if self._on_file is not None:
            self._on_file(report)


def recording_files(paths: Iterable[str | Path]) -> list[Path]:
    """The files ``paths`` name, a directory standing for its ``*.mcap`` in name (that
    is, time) order; RecordingError for a path that is neither."""
    found: list[Path] = []
    for given in paths:
        path = Path(given)
        if path.is_dir():
            inside = sorted(path.glob("*" + SUFFIX))
            if not inside:
                raise RecordingError(f"{path}: no {SUFFIX} files in this directory")
            found.extend(inside)
        elif path.is_file():
            found.append(path)
        elif path.exists():
            raise RecordingError(f"{path}: not a file or a directory")
        else:
            raise RecordingError(f"{path}: no such file or directory")
    return found


def unreadable(path: Path) -> str:
    """Why ``path`` cannot be read as a recording at all; empty if it can."""
    try:
        with path.open("rb") as stream:
            head = stream.read(len(MAGIC))
    except OSError as error:
        return str(error.strerror or error)
    if not head:
        return "empty"
    return "" if head == MAGIC else "not an MCAP file"


def check_readable(path: Path) -> None:
    """RecordingError unless ``path`` opens as an MCAP file."""
    why = unreadable(path)
    if why:
        raise RecordingError(f"{path}: {why}")


def usable_files(given: Iterable[str | Path]) -> list[Path]:
    """The files ``given`` names (as recording_files), RecordingError if not one of them
    can be read: a file among others that cannot is skipped when read, with a line."""
    paths = recording_files(given)
    problems = [(path, unreadable(path)) for path in paths]
    if paths and all(why for _, why in problems):
        path, why = problems[0]
        more = f" (and {len(paths) - 1} more that cannot be read)" if len(paths) > 1 else ""
        raise RecordingError(f"{path}: {why}{more}")
    return paths


def read(path: Path, reading: Reading, topics: Iterable[str] | None = None
         ) -> Iterator[Entry]:
    """The messages of one file, in the order written, past any damage; what was
    skipped (the whole file, or stretches of it) goes in a report added to ``reading``."""
    report = FileReport(path)
    reading.files.append(report)
    report.skipped = unreadable(path)
    if not report.skipped:
        wanted = None if topics is None else frozenset(topics)
        try:
            with path.open("rb") as stream:
                yield from _Walk(stream, report).entries(wanted)
        except OSError as error:  # the disk failing under the reader
            report.skipped = (f"reading failed after {report.read:,} messages: "
                              f"{error.strerror or error}")
    reading.done(report)


def read_all(paths: Iterable[Path], reading: Reading,
             topics: Iterable[str] | None = None) -> Iterator[Entry]:
    for path in paths:
        yield from read(path, reading, topics)


class _Walk:
    """One MCAP file read record by record, skipping what cannot be read."""

    def __init__(self, stream: IO[bytes], report: FileReport) -> None:
        self._stream = stream
        self._report = report
        self._size = os.fstat(stream.fileno()).st_size
        self._channels: dict[int, str] = {}
        self._waiting: list[Loss] = []
        """Losses waiting for the next message read: when they ended."""
        self._counting: Loss | None = None
        """A damaged chunk, whose message index (after it) counts its messages."""

    def _at(self, offset: int, size: int) -> bytes:
        self._stream.seek(offset)
        return self._stream.read(size)

    def entries(self, wanted: frozenset[str] | None) -> Iterator[Entry]:
        end = self._summary()
        at = len(MAGIC)
        while at < end:
            head = self._at(at, _RECORD_HEAD.size)
            opcode, length = _RECORD_HEAD.unpack(head) if len(head) == _RECORD_HEAD.size \
                else (0, 0)
            after = at + _RECORD_HEAD.size + length
            if not _known(opcode) or after > end:
                at = self._resync(at, end, chunk=opcode == Opcode.CHUNK)
                continue
            if opcode == Opcode.DATA_END:
                self._report.whole = True
                break
            if opcode == Opcode.CHUNK:
                found = self._chunk(self._at(at + _RECORD_HEAD.size, length))
                if found is None:
                    at = self._damaged_chunk(at, after, end)
                    continue
                self._counting = None
                for channel, log_time, publish_time, data in found:
                    entry = self._entry(channel, log_time, publish_time, data)
                    if entry is not None and (wanted is None or entry.topic in wanted):
                        yield entry
            elif opcode in (Opcode.MESSAGE, Opcode.CHANNEL, Opcode.MESSAGE_INDEX):
                body = self._at(at + _RECORD_HEAD.size, length)
                try:
                    entry = self._top_level(opcode, body)
                except (struct.error, UnicodeDecodeError):
                    at = self._resync(at, end, chunk=False)
                    continue
                if entry is not None and (wanted is None or entry.topic in wanted):
                    yield entry
            at = after
        if at >= end and end < self._size:
            self._report.whole = True  # at the summary of a finished file

    def _summary(self) -> int:
        """Where the data section ends: a finished file's summary (its channels and
        message count read here), else the end of the file."""
        if self._size < len(MAGIC) + _FOOTER_BYTES:
            return self._size
        tail = self._at(self._size - _FOOTER_BYTES, _FOOTER_BYTES)
        opcode, length = _RECORD_HEAD.unpack_from(tail)
        if tail[-len(MAGIC):] != MAGIC or opcode != Opcode.FOOTER or length != 20:
            return self._size
        footer = self._size - _FOOTER_BYTES
        start, offsets, _ = struct.unpack_from("<QQI", tail, _RECORD_HEAD.size)
        if not len(MAGIC) <= start <= footer:
            return footer
        summary = self._at(start, (offsets if start < offsets <= footer else footer) - start)
        at = 0
        try:
            while at + _RECORD_HEAD.size <= len(summary):
                opcode, length = _RECORD_HEAD.unpack_from(summary, at)
                body = summary[at + _RECORD_HEAD.size:at + _RECORD_HEAD.size + length]
                if opcode == Opcode.CHANNEL:
                    channel, topic = _channel(body)
                    self._channels[channel] = topic
                elif opcode == Opcode.STATISTICS:
                    (self._report.expected,) = struct.unpack_from("<Q", body)
                at += _RECORD_HEAD.size + length
        except (struct.error, UnicodeDecodeError):
            pass  # a damaged summary: the data section read alone says what is there
        return start

    def _chunk(self, body: bytes) -> list[tuple[int, int, int, bytes]] | None:
        """(channel, log_time, publish_time, data) of a chunk's messages, its channels
        registered; None if the chunk is damaged (nothing of it is used then)."""
        try:
            _, _, size, crc, width = _CHUNK_HEAD.unpack_from(body)
            compression = body[_CHUNK_HEAD.size:_CHUNK_HEAD.size + width].decode()
            (stored,) = struct.unpack_from("<Q", body, _CHUNK_HEAD.size + width)
            data = body[_CHUNK_HEAD.size + width + 8:]
            if len(data) != stored:
                return None
            if size > _LARGEST_CHUNK:
                return None
            records = _decompress(compression, data, size)
            if len(records) != size or (crc and zlib.crc32(records) != crc):
                return None
            return self._records(records)
        # a damaged chunk fails in whatever decodes it (a struct, the decompressor, a
        # name's UTF-8): every one of them means the same, the chunk is skipped
        except Exception:
            return None

    def _records(self, records: bytes) -> list[tuple[int, int, int, bytes]]:
        """The messages of a chunk's records, whose CRC held (struct.error if their
        framing does not add up all the same)."""
        found = []
        channels = {}
        at = 0
        while at < len(records):
            opcode, length = _RECORD_HEAD.unpack_from(records, at)
            body_at = at + _RECORD_HEAD.size
            at = body_at + length
            if at > len(records):
                raise struct.error("a record runs past its chunk")
            if opcode == Opcode.MESSAGE:
                channel, _, log_time, publish_time = _MESSAGE_HEAD.unpack_from(records,
                                                                                body_at)
                found.append((channel, log_time, publish_time,
                              records[body_at + _MESSAGE_HEAD.size:at]))
            elif opcode == Opcode.CHANNEL:
                channel, topic = _channel(records[body_at:at])
                channels[channel] = topic
        self._channels.update(channels)
        return found

    def _top_level(self, opcode: int, body: bytes) -> Entry | None:
        """A record outside chunks: a message (an unchunked file), a channel, or the
        message index of the chunk before it."""
        if opcode == Opcode.CHANNEL:
            channel, topic = _channel(body)
            self._channels[channel] = topic
        elif opcode == Opcode.MESSAGE_INDEX:
            _, width = struct.unpack_from("<HI", body)
            if self._counting is not None:
                self._counting.messages = (self._counting.messages or 0) + width // 16
        else:
            channel, _, log_time, publish_time = _MESSAGE_HEAD.unpack_from(body)
            return self._entry(channel, log_time, publish_time, body[_MESSAGE_HEAD.size:])
        return None

    def _entry(self, channel: int, log_time: int, publish_time: int,
               data: bytes) -> Entry | None:
        topic = self._channels.get(channel)
        if topic is None:
            self._report.orphans += 1
            return None
        self._report.read += 1
        self._report.last = log_time
        for loss in self._waiting:
            loss.before = log_time
        self._waiting.clear()
        return Entry(topic, log_time, publish_time, data)

    def _lost(self, offset: int, size: int, chunk: bool) -> Loss:
        loss = Loss(offset, size, chunk, after=self._report.last)
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
        head = self._at(at, _RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            return False
        opcode, length = _RECORD_HEAD.unpack(head)
        return _known(opcode) and at + _RECORD_HEAD.size + length <= end

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
            block = self._at(offset, min(_SCAN_BYTES, end - offset))
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
        head = self._at(at, _RECORD_HEAD.size + _CHUNK_HEAD.size)
        if len(head) < _RECORD_HEAD.size + _CHUNK_HEAD.size:
            return False
        _, length = _RECORD_HEAD.unpack_from(head)
        start, stop, _, _, width = _CHUNK_HEAD.unpack_from(head, _RECORD_HEAD.size)
        if width > 16 or start > stop or at + _RECORD_HEAD.size + length > end:
            return False
        body_at = at + _RECORD_HEAD.size
        stored = self._at(body_at + _CHUNK_HEAD.size + width, 8)
        if len(stored) < 8 or struct.unpack("<Q", stored)[0] != (
                length - _CHUNK_HEAD.size - width - 8):
            return False
        # (read twice when it is the one: a chunk found this way is rare)
        return self._chunk(self._at(body_at, length)) is not None


_OPCODES = frozenset(int(opcode) for opcode in Opcode)


def _known(opcode: int) -> bool:
    """An opcode a record can have: where another is found, the framing is broken."""
    return opcode >= _PRIVATE_OPCODES or opcode in _OPCODES


def _channel(body: bytes) -> tuple[int, str]:
    """(id, topic) of a channel record's body."""
    channel, _, width = struct.unpack_from("<HHI", body)
    topic = body[8:8 + width]
    if len(topic) != width:
        raise struct.error("a channel's topic runs past its record")
    return channel, topic.decode()


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(data)
    if compression == "":
        return data
    raise ValueError(f"unknown compression {compression!r}")
