"""Recordings on disk: MCAP files, what their channels hold, and reading them back.

A recording is readable by any MCAP reader (Foxglove, PlotJuggler, the ``mcap``
package); this module is the one place that knows its channels:

- ``serial``: every read from the base station, the bytes exactly as read;
  ``log_time`` the read's UNIX time, ``publish_time`` its time on the host's monotonic
  clock (both ns), so a replay feeds the clock estimate the very pairs it saw live;
- ``serial/written``: every write to the base station, stamped the same way, so a
  capture shows both directions of the line;
- ``gx2/<address>/<record>`` and ``gx2/gateway/status``: each published message as one
  JSON object (NaN as null); ``log_time`` its ``host_time`` (for a status, its
  ``gateway.time``), ``publish_time`` its ``time`` where it has one.

Files are written in the order things happened, so reading a file front to back (which
also works on a file whose writer was killed before it finished) gives them in order.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.reader import NonSeekingReader
from mcap.writer import CompressionType, Writer

from gateway.common.jsontext import compact
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
        self.messages = 0

    def _channel(self, topic: str, encoding: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._writer.register_channel(
                topic, encoding, schema_id=0)
        return channel

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

    def finish(self) -> None:
        """Write the summary and index, make sure the disk has it all, close the file."""
        self._writer.finish()
        self._output.flush()
        with contextlib.suppress(OSError, AttributeError, io.UnsupportedOperation):
            os.fsync(self._output.fileno())
        self._output.close()


# --- reading --------------------------------------------------------------------------------

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


def check_readable(path: Path) -> None:
    """RecordingError unless ``path`` opens as an MCAP file."""
    try:
        with path.open("rb") as stream:
            head = stream.read(8)
    except OSError as error:
        raise RecordingError(f"{path}: {error.strerror or error}") from None
    if head != b"\x89MCAP0\r\n":
        raise RecordingError(f"{path}: not an MCAP file")


def read(path: Path, topics: Iterable[str] | None = None,
         incomplete: list[Path] | None = None) -> Iterator[Entry]:
    """The messages of one file, in the order written. A file whose writer was killed
    ends early rather than failing: it is appended to ``incomplete`` if given."""
    check_readable(path)
    wanted = None if topics is None else frozenset(topics)
    with path.open("rb") as stream:
        reader = NonSeekingReader(stream)
        try:
            for _, channel, message in reader.iter_messages(log_time_order=False):
                if wanted is None or channel.topic in wanted:
                    yield Entry(channel.topic, message.log_time, message.publish_time,
                                message.data)
        # a damaged tail fails in whatever the reader was parsing (a struct, a
        # decompressor, a length): every one of them ends the file where it broke
        except Exception as error:
            if incomplete is None:
                raise RecordingError(f"{path}: cut short ({error})") from None
            incomplete.append(path)


def read_all(paths: Iterable[Path], topics: Iterable[str] | None = None,
             incomplete: list[Path] | None = None) -> Iterator[Entry]:
    for path in paths:
        yield from read(path, topics, incomplete)
