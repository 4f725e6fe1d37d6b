"""Recording what the gateway reads, writes and publishes, to MCAP files, off the loop.

The event loop only appends to a bounded deque (a few hundred nanoseconds); a thread
of its own encodes, compresses and writes. The loop never waits for the disk: when
the queue is full, or the disk fails, messages are dropped and counted, never held.

The thread wakes every WAKE_S, writes what is queued, and flushes the chunk in
progress at least every FLUSH_S, so a process killed without warning leaves a file
readable up to about the last second. Files are finished (summary and index) when
they rotate, by age or size, and when the gateway stops. After a write fails (a full
disk) the file is closed as it is (readable up to its last flush) and a new one is
tried every RETRY_S; meanwhile messages are dropped and counted.

Closing is bounded, so that the gateway keeps its promise to exit within 2 s: close()
is given what is left of it. The thread writes what is queued for DRAIN_SHARE of that
time and drops the rest (counted), then finishes the file: the chunk in progress, the
summary and the index. A disk too slow even for that is left behind when the time is
up, and one line says so: the file then holds what reached the disk, its chunks up to
the last one written whole (at the last flush, about a second before, or since) and
perhaps part of the next, without a summary or index. An MCAP reader reading it front
to back (``mcap``'s NonSeekingReader, ``gx2ctl export``) gets every message of those
whole chunks, then finds the file cut short.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from gateway.recording.files import WRITTEN, RecordingWriter, file_name

from .config import RecordConfig

log = logging.getLogger("gx2.record")
WAKE_S = 0.1
FLUSH_S = 1.0
RETRY_S = 5.0
CLOSE_S = 1.0
"""What close() takes at the most unless told otherwise."""
DRAIN_SHARE = 0.5
"""The share of close()'s time the queue may take; the rest is the last chunk's and the
summary's (a handful of writes)."""
SERIAL, SENT, PUBLISHED = 0, 1, 2
"""What a queued item is: a read, a write, a published message."""


def exclusive(path: Path) -> IO[bytes]:
    """A new file, never one that exists."""
    return path.open("xb")


class Recorder:
    """``serial``/``written``/``published`` on the loop; everything else in its thread."""

    def __init__(self, config: RecordConfig, metadata: dict[str, str],
                 create: Callable[[Path], IO[bytes]] | None = None) -> None:
        self.create = create or exclusive
        """Opens a new file for writing (a test's slow disk stands in here)."""
        self.directory = Path(config.directory)
        self.rotate_s = config.rotate_minutes * 60
        self.rotate_bytes = int(config.rotate_mb * 1e6)
        self.capacity = config.queue
        self.metadata = metadata
        self._queue: deque[tuple[Any, ...]] = deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gx2-recorder", daemon=True)
        # one counter per thread: neither ever adds to the other's
        self.overflowed = 0
        """Messages the loop dropped: the queue was full."""
        self.lost = 0
        """Messages the thread could not write: the disk failed."""
        self.written = 0
        self.errors = 0
        self.files = 0
        self.last_error = ""
        self.path: Path | None = None
        self._writer: RecordingWriter | None = None
        self._output: Any = None
        self._opened = 0.0
        self._unflushed = 0
        self._retry_at = 0.0
        self._closing = False
        self._drain_until = 0.0
        """Once closing, the time.monotonic() past which no more of the queue is written."""
        self.cut = 0
        """Messages still queued when the queue's share of close()'s time ran out."""

    # -- the loop's side: never blocks, never grows past the bound -------------------------

    def serial(self, data: bytes, host_time: float, monotonic: float) -> None:
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((SERIAL, data, host_time, monotonic))
        else:
            self.overflowed += 1

    def sent(self, data: bytes, host_time: float, monotonic: float) -> None:
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((SENT, bytes(data), host_time, monotonic))
        else:
            self.overflowed += 1

    def published(self, topic: bytes, payload: dict[str, Any]) -> None:
        """A published message. The payload is not copied: the gateway makes a new map
        for every message and never changes one once published."""
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((PUBLISHED, topic, payload))
        else:
            self.overflowed += 1

    @property
    def dropped(self) -> int:
        """Messages never written: the queue was full, or the disk failed."""
        return self.overflowed + self.lost

    def status(self) -> dict[str, Any]:
        return {"directory": str(self.directory), "file": str(self.path or ""),
                "files": self.files, "written": self.written, "queued": len(self._queue),
                "dropped": self.dropped, "errors": self.errors, "error": self.last_error}

    def start(self) -> None:
        self._thread.start()

    def close(self, timeout: float = CLOSE_S) -> None:
        """Write what is queued and finish the file, within ``timeout`` s (see the
        module's docstring for what the file holds when the disk is slower), and end
        the thread."""
        self._drain_until = time.monotonic() + DRAIN_SHARE * timeout
        self._closing = True
        self._stop.set()
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("recording: %s left unfinished: the disk took more than %.2f s; it "
                        "holds what was written, readable up to its last whole chunk, "
                        "without a summary (%d messages were still queued)", self.path,
                        timeout, self.cut + len(self._queue))
        elif self.cut:
            log.warning("recording: %s finished without the last %d messages: the disk "
                        "did not take them within %.2f s", self.path, self.cut, timeout)

    # -- the thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        last_flush = time.monotonic()
        while not self._stop.wait(WAKE_S):
            self._drain()
            now = time.monotonic()
            if self._writer is not None and now - last_flush >= FLUSH_S:
                last_flush = now
                self._guarded(self._flush)
        self._drain()
        self.cut = len(self._queue)
        self.lost += self.cut
        self._queue.clear()
        self._guarded(self._finish)  # (the chunk in progress, then the summary)

    def _drain(self) -> None:
        """Write what is queued (once closing, until the queue's time is up: a backlog
        the thread was writing when close() came is bounded too)."""
        queue = self._queue
        while queue:
            if self._closing and time.monotonic() >= self._drain_until:
                return
            item = queue.popleft()
            writer = self._writer or self._open()
            if writer is None:
                self.lost += 1
                continue
            if not self._guarded(self._write, writer, item):
                self.lost += 1

    def _write(self, writer: RecordingWriter, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == PUBLISHED:
            writer.message(item[1].decode(), item[2])
        elif kind == SERIAL:
            writer.serial(item[1], item[2], item[3])
        else:
            writer.serial(item[1], item[2], item[3], topic=WRITTEN)
        self.written += 1
        self._unflushed += 1

    def _flush(self) -> None:
        self._writer.flush()  # type: ignore[union-attr]
        self._unflushed = 0
        if (time.monotonic() - self._opened >= self.rotate_s
                or self._output.tell() >= self.rotate_bytes):
            self._finish()
            self._open()

    def _open(self) -> RecordingWriter | None:
        """A new file, or None while the last failure's retry time has not come."""
        if time.monotonic() < self._retry_at:
            return None
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            path = self.directory / file_name()
            while path.exists():  # two files within a millisecond (a tiny rotate_mb)
                time.sleep(0.001)
                path = self.directory / file_name()
            self._output = self.create(path)
            self._writer = RecordingWriter(self._output, self.metadata)
        except OSError as error:
            self._failed(error)
            return None
        self.path = path
        self.files += 1
        self._opened = time.monotonic()
        log.info("recording to %s", path)
        return self._writer

    def _finish(self) -> None:
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        writer.finish()
        self._output = None

    def _guarded(self, action: Any, *args: Any) -> bool:
        """Run a disk action; on failure, count it, drop the file and say so."""
        try:
            action(*args)
        except OSError as error:
            self._failed(error)
            return False
        return True

    def _failed(self, error: OSError) -> None:
        why = error.strerror or str(error)
        self.errors += 1
        if why != self.last_error:
            log.error("recording to %s failed: %s; messages are dropped (and counted) "
                      "until a new file can be written, tried every %g s",
                      self.directory, why, RETRY_S)
        self.last_error = why
        # what the failed file holds up to its last flush stays readable
        self.lost += self._unflushed
        self._unflushed = 0
        if self._output is not None:
            with contextlib.suppress(OSError, ValueError):
                self._output.close()
        self._writer = self._output = None
        self._retry_at = time.monotonic() + RETRY_S
