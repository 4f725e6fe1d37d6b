"""Writing a recording: one MCAP file, its channels registered as they first appear
(see :mod:`.files` for what each holds)."""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from gateway.common.jsontext import compact, compact_bytes
from gateway.common.schemas import ENCODING as SCHEMA_ENCODING
from gateway.common.schemas import schema_for_topic
from gateway.common.version import installed

from .files import (
    CHUNK_BYTES,
    END,
    JSON_ENCODING,
    METADATA,
    PROFILE,
    RAW_ENCODING,
    SERIAL_READS,
    claim,
    message_times,
    ns,
)


class RecordingWriter:
    """One MCAP file being written: channels registered as they first appear."""

    def __init__(self, output: IO[bytes], metadata: Mapping[str, str] | None = None) -> None:
        self._output = output
        claim(output)  # (readers tell it from a file whose writer was killed)
        self._writer = Writer(output, chunk_size=CHUNK_BYTES,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"gx2-gateway {installed()}")
        if metadata:
            self._writer.add_metadata(METADATA, dict(metadata))
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
               topic: str = SERIAL_READS) -> None:
        """A read from (or, with ``topic=WRITTEN``, a write to) the base station;
        OutOfRange, and nothing written, if a time cannot be recorded."""
        logged, sampled = ns(host_time), ns(monotonic)
        self.messages += 1
        self._writer.add_message(self._channel(topic, RAW_ENCODING), logged, data,
                                 sampled, self.messages)

    def message(self, topic: str, payload: Mapping[str, Any],
                data: bytes | None = None, times: tuple[float, float] | None = None
                ) -> None:
        """A published message: a node's record or frame, or the gateway's status
        (``data``: its JSON, if it has been made already; ``times``: its (logged,
        sampled) UNIX times, if its payload does not say them as a record's does);
        OutOfRange, and nothing written, if its times cannot be recorded (mcap would
        fail part-way, its statistics already holding them, and then fail to finish
        the file)."""
        logged, sampled = (ns(when) for when in times or message_times(payload))
        if data is None:
            data = compact_bytes(payload)
        self.messages += 1
        self._writer.add_message(self._channel(topic, JSON_ENCODING), logged, data,
                                 sampled, self.messages)

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
                output.write(END)

    def finish(self) -> None:
        """Write the summary and index, make sure the disk has it all, close the file."""
        self._writer.finish()
        self._output.flush()
        with contextlib.suppress(OSError, AttributeError, io.UnsupportedOperation):
            os.fsync(self._output.fileno())
        self._output.close()
