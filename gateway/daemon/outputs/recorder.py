"""Recording what the gateway reads, writes and publishes, to MCAP files, off the loop.

The event loop only appends to a bounded deque (a few hundred nanoseconds); a thread
of its own encodes, compresses and writes. The loop never waits for the disk: when
the queue is full, or the disk fails, messages are dropped and counted, never held.

The thread wakes every WAKE_S, writes what is queued, and flushes the chunk in
progress at least every FLUSH_S, so a process killed without warning leaves a file
readable up to about the last second. Files are finished (summary and index) when
they rotate, by age or size, and when the gateway stops. The flush, rotation and
retention keep their second under any load (issue 31): a queue that never empties (a
disk slower than what comes) is written until they are due, not until it is empty,
and overflows meanwhile (counted), so a slow disk drops messages, never postpones them
(late at most by the one write the disk is taking).

A disk that fails (full, an I/O error, a directory that cannot be made) is loud and
leaves nothing broken behind (issue 20): the recorder's ``failure`` says why it
cannot write, which makes the gateway's own health ERROR (:mod:`.health`). A file that
could not be started (created, but its header could not be written) is removed, never
left empty; a file cut short is cut back to its last flush and ended there (a data end
and a footer, as the MCAP spec allows), so every reader reads it whole, and removed if
that flush kept nothing (``RecordingWriter.abandon``). Meanwhile messages are dropped
and counted, and a new file is tried every RETRY_S; recording has resumed, and says
so, once RESUMED_AFTER flushes of the new file in a row have put messages on the disk
(a file created on a full disk is not yet a file written, nor is one flush a disk that
keeps taking them).

A message the file cannot take (a time no MCAP timestamp holds: a replayed ``time`` in
nanoseconds) is refused before mcap has any of it, counted in ``dropped`` and said once
per kind; the thread goes on with the next (issue 31: one such message ended it, and
the file with it). No exception ends the thread quietly: one of the file's that is not
the disk's (a bug) fails the file as a full disk would, with its traceback; one that
still ends the thread is logged, and ``failure`` says so (the gateway is ERROR).

A mark (``gx2ctl mark``) is flushed as soon as it is written, and :meth:`Recorder.kept`
lets the mark's answer wait for that (issue 43: export, ``recordings`` and
``Recording`` did not see a mark for up to a second after ``mark`` returned).

Retention (``record.keep_gb``, ``record.keep_days``; :mod:`.retention`) runs in the
same thread once a second.

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

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from gateway.common.topics import MARK_TOPIC
from gateway.recording.files import SERIAL_READS, WRITTEN, OutOfRange, file_name
from gateway.recording.writer import RecordingWriter

from ..config import RecordConfig
from . import Message, Needs, Output
from .retention import Retention

log = logging.getLogger("gx2.record")
WAKE_S = 0.1
FLUSH_S = 1.0
"""Also how often retention looks at the directory's files."""
RETRY_S = 5.0
RESUMED_AFTER = 3
"""Flushes of a new file in a row that put messages on the disk before recording has
resumed: one that fits in the little a full disk gave back (the partial chunk cut off
the failed file) is not yet a disk that takes what comes (issue 31: it said "resumed",
and was ERROR again a second later)."""
CLOSE_S = 1.0
"""What close() takes at the most unless told otherwise."""
DRAIN_SHARE = 0.5
"""The share of close()'s time the queue may take; the rest is the last chunk's and the
summary's (a handful of writes)."""
QUEUED_READ, QUEUED_WRITE, QUEUED_MESSAGE = 0, 1, 2
"""What a queued item is: a read, a write, a published message."""
MARK_KEPT_S = 1.0
"""The longest a mark's answer waits for the mark to be on the disk (a disk slower than
that: it is written all the same, with the next flush)."""


def exclusive(path: Path) -> IO[bytes]:
    """A new file, never one that exists."""
    return path.open("xb")


class Recorder(Output):
    """``serial``/``sent``/``take`` on the loop; everything else in its thread."""

    def __init__(self, config: RecordConfig, metadata: dict[str, str],
                 create: Callable[[Path], IO[bytes]] | None = None) -> None:
        self.create = create or exclusive
        """Opens a new file for writing (a test's slow disk stands in here)."""
        self.directory = Path(config.directory)
        self.rotate_s = config.rotate_minutes * 60
        self.rotate_bytes = int(config.rotate_mb * 1e6)
        self.retention = Retention(self.directory, config.keep_gb, config.keep_days)
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
        """Messages on the disk: handed to the OS by a flush (or a finish)."""
        self.refused = 0
        """Messages the thread could not write at all (a time no recording can hold)."""
        self._refusals: set[str] = set()
        """The kinds of refusal already logged: each is said once."""
        self.errors = 0
        self.files = 0
        self.last_error = ""
        self._failure = ""
        """Why nothing can be written now ("" while files are written)."""
        self._crash = ""
        """What ended the thread, if an exception did (a bug)."""
        self._lost_before = 0
        """``lost`` when the failure began: what resuming says was dropped."""
        self.path: Path | None = None
        """The file being written, or the last one."""
        self._writer: RecordingWriter | None = None
        self._output: Any = None
        """The file being written, open (None between files)."""
        self._opened = 0.0
        self._proven = 0
        """Flushes of this file that put messages on the disk (while failed)."""
        self._unflushed = 0
        self._retry_at = 0.0
        self._closing = False
        self._ended = False
        """A file was finished while closing: no other is opened (see _flush)."""
        self._drain_until = 0.0
        """Once closing, the time.monotonic() past which no more of the queue is written."""
        self.cut = 0
        """Messages still queued when the queue's share of close()'s time ran out."""
        self._marks_taken = 0
        """Marks queued (the loop's count)."""
        self._marks_done = 0
        """Of them, those the thread is done with: flushed to the disk, or lost."""
        self._kept_waiters: list[tuple[int, asyncio.Future[None]]] = []
        """(marks taken, future) of each :meth:`kept` waiting; under ``_marks_lock``."""
        self._marks_lock = threading.Lock()

    # -- the loop's side: never blocks, never grows past the bound -------------------------

    def serial(self, data: bytes, host_time: float, monotonic: float,
               channel: str = SERIAL_READS) -> None:
        """A read from a base station, kept on ``channel`` (its station's)."""
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((QUEUED_READ, data, host_time, monotonic, channel))
        else:
            self.overflowed += 1

    def sent(self, data: bytes, host_time: float, monotonic: float,
             channel: str = WRITTEN) -> None:
        """A write to a base station, kept on ``channel`` (its station's)."""
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((QUEUED_WRITE, bytes(data), host_time, monotonic, channel))
        else:
            self.overflowed += 1

    def take(self, message: Message) -> None:
        """A published message. Not copied: the gateway makes a new map for every
        message and never changes one once published; its JSON is made in the thread
        (or was already, by the live view)."""
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((QUEUED_MESSAGE, message.topic, message))
            if message.topic == MARK_TOPIC:
                self._marks_taken += 1
        else:
            self.overflowed += 1

    async def kept(self, timeout: float = MARK_KEPT_S) -> bool:
        """Wait (on the loop) until every mark taken so far is on the disk, flushed
        (or lost to a failing disk), at most ``timeout`` s; whether it came to that.
        A waiter that gave up is forgotten (on a slow disk they piled up, one a mark)."""
        loop = asyncio.get_running_loop()
        with self._marks_lock:
            if self._marks_done >= self._marks_taken:
                return True
            future: asyncio.Future[None] = loop.create_future()
            waiter = (self._marks_taken, future)
            self._kept_waiters.append(waiter)
        try:
            await asyncio.wait_for(future, timeout)
        except TimeoutError:
            return False
        finally:
            with self._marks_lock:  # (the thread's _mark_done took it if it was done)
                if waiter in self._kept_waiters:
                    self._kept_waiters.remove(waiter)
        return True

    def _mark_done(self) -> None:
        """The thread is done with a mark: the waiters it was the last of, woken."""
        with self._marks_lock:
            self._marks_done += 1
            ready = [f for taken, f in self._kept_waiters if taken <= self._marks_done]
            self._kept_waiters = [(taken, f) for taken, f in self._kept_waiters
                                  if taken > self._marks_done]
        for future in ready:
            with contextlib.suppress(RuntimeError):  # (its loop closed: nobody waits)
                future.get_loop().call_soon_threadsafe(_resolve, future)

    @property
    def dropped(self) -> int:
        """Messages never written: the queue was full, the disk failed, or the message
        could not be written."""
        return self.overflowed + self.lost + self.refused

    @property
    def failure(self) -> str:
        """Why the recorder cannot write now, or "" while it writes (read on the loop:
        one attribute, set by the thread)."""
        if self._thread.ident is not None and not self._thread.is_alive() \
                and not self._closing:
            return f"its thread stopped ({self._crash})" if self._crash \
                else "its thread stopped"
        return self._failure

    def status(self) -> dict[str, Any]:
        return {"directory": str(self.directory),
                "file": str(self.path) if self._output is not None else "",
                "files": self.files, "written": self.written, "queued": len(self._queue),
                "dropped": self.dropped, "errors": self.errors, "error": self.last_error,
                "failure": self.failure, "bytes": self.retention.bytes,
                "oldest": self.retention.oldest}

    def start(self) -> None:
        self._thread.start()

    def close(self, timeout: float = CLOSE_S) -> None:  # (seconds: the contract's)
        """Write what is queued and finish the file, within ``timeout`` s (see the
        module's docstring for what the file holds when the disk is slower), and end
        the thread."""
        if self._thread.ident is None:  # never started (a start that failed): no file
            return
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
        try:
            self._record()
        except Exception as error:  # (a bug: never silent, and the gateway is ERROR)
            self.errors += 1
            self.last_error = f"{type(error).__name__}: {error}"
            self._crash = self.last_error
            log.exception("recording stopped: its thread failed (%s); nothing more is "
                          "recorded", self.last_error)

    def _record(self) -> None:
        self.retention.list(self._writing())
        # The flush, rotation and retention are due once a second whatever the load: a
        # queue that never empties (a disk slower than what comes) is written until the
        # next one is due, never past it, and overflows meanwhile (counted: the loop's
        # side drops what does not fit). Waiting happens only on an empty queue.
        due = time.monotonic() + FLUSH_S
        while True:
            backlog = self._drain(due)
            if time.monotonic() >= due:
                if self._writer is not None:
                    self._guarded(self._flush)
                if not self._closing:  # (see _flush)
                    self._retain()
                due = time.monotonic() + FLUSH_S
            if backlog:
                if self._stop.is_set():
                    break
            elif self._stop.wait(WAKE_S):
                break
        self._drain(self._drain_until)
        self.cut = len(self._queue)
        self.lost += self.cut
        self._queue.clear()
        self._guarded(self._finish)  # (the chunk in progress, then the summary)

    def _drain(self, until: float) -> bool:
        """Write what is queued until time.monotonic() reaches ``until`` (once closing,
        until the queue's share of close()'s time is up: a backlog the thread was
        writing when close() came is bounded too); whether some is left."""
        queue = self._queue
        while queue:
            now = time.monotonic()
            if now >= until or (self._closing and now >= self._drain_until):
                return True
            item = queue.popleft()
            writer = self._writer or (None if self._ended else self._open())
            marked = item[0] == QUEUED_MESSAGE and item[1] == MARK_TOPIC
            if writer is None or not self._guarded(self._write, writer, item):
                self.lost += 1
            elif marked:
                self._guarded(self._flush)  # (readable at once, by anyone)
            if marked:
                self._mark_done()
        return False

    def _write(self, writer: RecordingWriter, item: tuple[Any, ...]) -> None:
        """One message into the file; one it cannot take (anything but the disk's
        failure) is refused, and the thread goes on with the next."""
        try:
            if item[0] == QUEUED_MESSAGE:
                message = item[2]
                writer.message(item[1].decode(), message.payload, message.json(),
                               message.times)
            else:
                writer.serial(item[1], item[2], item[3], topic=item[4])
        except OSError:
            raise
        except Exception as error:  # (the message's: the thread survives any)
            self._refuse(item, error)
            return
        self._unflushed += 1

    def _refuse(self, item: tuple[Any, ...], error: Exception) -> None:
        """A message not written, counted; the first of each kind said in one line (with
        its traceback if it is not a time out of range: a bug, here or in mcap)."""
        self.refused += 1
        topic = item[1].decode(errors="replace") if item[0] == QUEUED_MESSAGE else item[4]
        kind = type(error).__name__
        if kind in self._refusals:
            return
        self._refusals.add(kind)
        log.error("recording: a message on %s cannot be recorded: %s; it and any other "
                  "such are dropped and counted (recording.dropped)", topic,
                  error if isinstance(error, OutOfRange) else f"{kind}: {error}",
                  exc_info=None if isinstance(error, OutOfRange) else error)

    def _flush(self) -> None:
        writer = self._writer
        before = writer.kept  # type: ignore[union-attr]
        writer.flush()  # type: ignore[union-attr]
        self.written += self._unflushed
        self._unflushed = 0
        if self._failure and writer.kept > before:  # type: ignore[union-attr]
            self._proven += 1
            if self._proven >= RESUMED_AFTER:
                self._resumed()
        # Once closing, the file is finished as it is: a disk slower than close()'s
        # time leaves the thread writing after close() returned, and a rotation or the
        # retention then opened a new file and deleted the one being closed. A rotation
        # that close() came during (the summary's write is the slow part) ends there.
        if not self._closing and (time.monotonic() - self._opened >= self.rotate_s
                                  or self._output.tell() >= self.rotate_bytes):
            self._finish()
            if self._closing:
                self._ended = True
            else:
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
            self.path = path
            self._writer = RecordingWriter(self._output, self.metadata)
            # its header on the disk now: a file that cannot even be started is found
            # out here and removed (a full disk left an empty file every retry)
            self._output.flush()
        except OSError as error:
            self._failed(error.strerror or str(error))
            return None
        self.files += 1
        self._opened = time.monotonic()
        self._proven = 0
        if self._failure:
            log.debug("recording: trying %s", path)
        else:
            log.info("recording to %s", path)
        self.retention.list(self._writing())
        return self._writer

    def _finish(self) -> None:
        writer, path = self._writer, self.path
        if writer is None or path is None:
            return
        writer.finish()
        self.written += self._unflushed
        self._unflushed = 0
        self._writer = self._output = None
        self.retention.add(path)

    def _guarded(self, action: Any, *args: Any) -> bool:
        """Run a disk action; on failure, count it, drop the file and say so. Any other
        exception (a bug, here or in mcap) is a failure of the file too, its traceback
        logged: what it left of the file may not be whole, and the thread goes on."""
        try:
            action(*args)
        except OSError as error:
            self._failed(error.strerror or str(error))
            return False
        except Exception as error:
            self._failed(f"{type(error).__name__}: {error}", error)
            return False
        return True

    def _failed(self, why: str, unexpected: Exception | None = None) -> None:
        self.errors += 1
        self.last_error = why
        if why != self._failure:
            if not self._failure:
                self._lost_before = self.lost
            log.error("recording to %s failed: %s; messages are dropped (and counted) "
                      "until a new file can be written, tried every %g s",
                      self.directory, why, RETRY_S, exc_info=unexpected)
            self._failure = why
        # what the failed file holds up to its last flush stays readable
        self.lost += self._unflushed
        self._unflushed = 0
        self._abandon()
        self._retry_at = time.monotonic() + RETRY_S

    def _abandon(self) -> None:
        """The file being written, after a failure: cut back to its last flush and ended
        there, or removed if that kept nothing."""
        writer, output, path = self._writer, self._output, self.path
        self._writer = self._output = None
        if output is None or path is None:
            return
        if writer is not None:
            writer.abandon(path)
        else:  # (created, its writer never started)
            with contextlib.suppress(OSError, ValueError):
                output.close()
            with contextlib.suppress(OSError):
                path.unlink()
        if path.exists():
            log.warning("recording: %s cut short, readable up to its last flush (%d "
                        "messages)", path, writer.kept if writer else 0)
            self.retention.add(path)
        else:
            log.debug("recording: %s removed: nothing of it reached the disk", path)

    def _resumed(self) -> None:
        log.warning("recording resumed in %s after %d messages dropped (%s)", self.path,
                    self.lost - self._lost_before, self._failure)
        self._failure = ""

    def _retain(self) -> None:
        """Retention, once a second: the file being written counts, never deleted."""
        size = 0
        if self._output is not None:
            with contextlib.suppress(OSError, ValueError):
                size = self._output.tell()
        self.retention.apply(self._writing(), size)

    def _writing(self) -> Path | None:
        return self.path if self._output is not None else None


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


def make(needs: Needs) -> Recorder:
    assert needs.config.record is not None
    return Recorder(needs.config.record, needs.metadata())
