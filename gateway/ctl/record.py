"""``gx2ctl record FILE.mcap [NODE...] [--seconds S]``: a running gateway's published
stream, recorded by a subscriber to an MCAP file with the channels the daemon's own
recordings have (no ``serial`` channel: a subscriber never sees the bytes), marks
(``gx2ctl mark``) included whichever nodes are recorded.

The file is made when the gateway is first heard (its heartbeat, a record, a mark):
one that publishes nothing in the wait for it (``--timeout``, and at least three
heartbeats) leaves no file behind, and the run exits 1. ``--seconds`` counts from
then. A progress line on stderr (records, rate, and the samples lost by the radio and
by the gateway: :mod:`gateway.recording.losses`) while it runs, in place on a terminal
and every PROGRESS_PIPE_S otherwise; the file is finished on a signal, at the
end of ``--seconds`` and when the gateway falls silent, and flushed every second
meanwhile. A disk that fails (full, a file size limit, an I/O error) ends the run with
one line (exit 1): the file keeps what was written up to the last flush, ended there so
readers read it whole, and is removed if that is nothing.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import zmq

from gateway.client import Message, Status, Subscriber
from gateway.common import curve
from gateway.common.protocol import MAX_REPLY_BYTES, Exit
from gateway.common.topics import MARK_TOPIC, topic
from gateway.recording.files import MARK, STATUS, SUFFIX
from gateway.recording.losses import Losses
from gateway.recording.summary import Summary
from gateway.recording.writer import RecordingWriter

from . import PROG
from .client import CtlError
from .sitestream import Silences, quiet_for, sources, subscribe_all
from .subscribing import Source, Stop, source

if TYPE_CHECKING:
    from .where import Gateway

FLUSH_S = 1.0
PROGRESS_S = 0.5
PROGRESS_PIPE_S = 10.0
WAIT_S = 0.1
"""The longest a mark waits to be written while nothing else arrives."""


def run_record(path: str, nodes: list[int], seconds: float | None,
               named: Sequence[Gateway], timeout: float) -> int:
    """Record from the gateways ``named`` (one, or several into one file: their nodes
    must differ, and the recording goes on while any of them publishes)."""
    target = Path(path)
    if target.suffix != SUFFIX:  # (x.csv would hold MCAP, and a directory skip it)
        raise CtlError(f"{target}: gx2ctl record writes MCAP: name the file "
                       f"{target.with_suffix(SUFFIX).name}", Exit.USAGE)
    if target.exists():
        raise CtlError(f"{target} exists: record to a new file", Exit.USAGE)
    creatable(target)
    stop = Stop()
    if len(named) == 1:
        found = [(named[0], source(nodes, named[0].where, timeout))]
    else:
        found = sources(nodes, named, timeout, every=True)
        apart(nodes, found)
    addresses = ", ".join(s.address for _, s in found)
    gateways = f"the gateway{'s' if len(found) > 1 else ''} at {addresses}"
    silence = max(s.silence for _, s in found)
    heartbeat = "its heartbeat" if len(found) == 1 else "a heartbeat"
    # the marks' sockets first: by the time the subscriber hears the gateway, they have
    # joined too, and a mark made once gx2ctl record shows its file is kept
    with contextlib.ExitStack() as stack:
        marks = [stack.enter_context(marks_of(s)) for _, s in found]
        sub = stack.enter_context(subscribe_all(nodes, found, status=True))
        events = Events(sub, marks)
        first = events.first(silence, stop)
        if first is None:
            why = (f"interrupted before {gateways} {'was' if len(found) == 1 else 'were'}"
                   " heard" if stop.requested else
                   f"no message from {gateways} in {silence:g} s, not even {heartbeat}")
            raise CtlError(f"{why}: nothing recorded ({target} not made)", Exit.NODE_FAILED)
        capture = Capture(target, {"recorded_by": "gx2ctl record", "source": addresses})
        progress = Progress(target, sys.stderr.isatty())
        silences = Silences(sub, found) if len(found) > 1 else None
        start = flushed = time.monotonic()
        event: Event | None = first
        try:
            while not stop.requested:
                if event is not None:
                    capture.add(event, progress)
                now = time.monotonic()
                if seconds is not None and now - start >= seconds:
                    break
                if now - flushed >= FLUSH_S:
                    capture.flush()
                    flushed = now
                    if silences is not None:
                        silences.check()  # one of several silent: said, the rest go on
                progress.show(now - start)
                if event is None and quiet_for(sub) > silence:
                    raise CtlError(f"{gateways} published nothing for {silence:g} s (not "
                                   f"even {heartbeat}); {target} holds what came before",
                                   Exit.NO_ANSWER)
                event = events.next(PROGRESS_S)
        finally:
            capture.finish()
            if not capture.failed:  # (a disk that failed: its line says it all)
                progress.done(time.monotonic() - start)
    return Exit.OK


def apart(nodes: Sequence[int], found: Sequence[tuple[Gateway, Source]]) -> None:
    """Usage error unless the nodes recorded are each of one gateway only: the file's
    channels are named by node address, and two nodes of one address would be mixed."""
    owner: dict[int, str] = {}
    for gateway, found_source in found:
        for node in found_source.nodes:
            if nodes and node not in nodes:
                continue
            if node in owner:
                raise CtlError(f"node {node} is in both {owner[node]} and {gateway.name}: "
                               "one file keeps one node of an address; record them to "
                               "separate files, or name the nodes to record", Exit.USAGE)
            owner[node] = gateway.name


def creatable(target: Path) -> None:
    """Usage error (exit 2) now, rather than once the gateway is heard, if ``target``
    cannot be made (no such directory, no permission); nothing is left behind. A file
    of another name in its directory is made and removed, never ``target`` itself: its
    appearing says the gateway is heard and a mark made from then on is kept (a test
    that waited for it once saw this probe, and made its mark before the marks were
    subscribed to)."""
    probe = target.with_name(f".{PROG}-{os.getpid()}.probe")
    try:
        probe.open("xb").close()
    except OSError as error:
        raise CtlError(f"{target}: {error.strerror or error}", Exit.USAGE) from None
    with contextlib.suppress(OSError):
        probe.unlink()


# --- what is received -----------------------------------------------------------------

@dataclass(frozen=True)
class Marked:
    """A mark published by the gateway (``gx2ctl mark``)."""

    payload: Mapping[str, Any]


Event = Message | Status | Marked


class Marks:
    """A subscription to the gateway's marks, beside the subscriber's records and
    heartbeats (which never yields them)."""

    def __init__(self, found: Source) -> None:
        self.context = zmq.Context()
        self.socket = self.context.socket(zmq.SUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)
        if found.keys is not None:
            curve.connect_as(self.socket, found.keys)
        self.socket.setsockopt(zmq.SUBSCRIBE, MARK_TOPIC)
        try:
            self.socket.connect(found.address)
        except zmq.ZMQError as error:
            self.close()
            raise CtlError(f"cannot subscribe to {found.address}: {error}",
                           Exit.USAGE) from None

    def take(self) -> Marked | None:
        """A mark already received, or None (a malformed one is skipped, with a line)."""
        while True:
            try:
                frames = self.socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return None
            try:
                payload = msgpack.unpackb(frames[-1], raw=False, strict_map_key=False)
            except Exception:  # msgpack raises several unrelated types
                payload = None
            if len(frames) == 2 and isinstance(payload, dict):
                return Marked(payload)
            print(f"{PROG}: skipped a mark that is not a msgpack map", file=sys.stderr,
                  flush=True)

    def close(self) -> None:
        self.socket.close(linger=0)
        self.context.term()


@contextlib.contextmanager
def marks_of(found: Source) -> Iterator[Marks]:
    marks = Marks(found)
    try:
        yield marks
    finally:
        marks.close()


class Events:
    """Records, heartbeats and marks as they come."""

    def __init__(self, sub: Subscriber, marks: Sequence[Marks]) -> None:
        self.sub = sub
        self.marks = marks

    def _mark(self) -> Marked | None:
        return next((m for marks in self.marks if (m := marks.take()) is not None), None)

    def next(self, timeout: float) -> Event | None:
        """The next event, or None after ``timeout`` s. A mark is looked for between
        records, and at least every WAIT_S while none comes."""
        deadline = time.monotonic() + timeout
        while True:
            mark = self._mark()
            if mark is not None:
                return mark
            left = deadline - time.monotonic()
            event = self.sub.receive(max(0.0, min(left, WAIT_S)))
            if event is not None:
                return event
            if left <= WAIT_S:
                return self._mark()

    def first(self, silence: float, stop: Stop) -> Event | None:
        """The first event, or None if the gateway stays silent for ``silence`` s (or
        a signal comes first)."""
        while not stop.requested and quiet_for(self.sub) <= silence:
            event = self.next(PROGRESS_S)
            if event is not None:
                return event
        return None


# --- what is written ------------------------------------------------------------------

class Capture:
    """The file being written. A disk error ends the run (exit 1) with one line, the
    file left as :meth:`RecordingWriter.abandon` leaves it."""

    def __init__(self, target: Path, metadata: dict[str, str]) -> None:
        self.target = target
        try:
            output = target.open("xb")
        except OSError as error:
            raise CtlError(f"{target}: {error.strerror or error}", Exit.USAGE) from None
        self.writer = RecordingWriter(output, metadata)
        self.failed = False
        """A write failed: the run ends, the file as abandon() left it."""

    def add(self, event: Event, progress: Progress) -> None:
        with self._guarded():
            if isinstance(event, Message):
                self.writer.message(topic(event.node, event.record).decode(), event.payload)
                progress.count(event)
            elif isinstance(event, Marked):  # (flushed: readable at once, as the
                self.writer.message(MARK, event.payload)  # gateway's own file keeps it)
                self.writer.flush()
            else:
                self.writer.message(STATUS, event.payload)
                progress.status(event)

    def flush(self) -> None:
        with self._guarded():
            self.writer.flush()

    def finish(self) -> None:
        if not self.failed:
            with self._guarded():
                self.writer.finish()

    @contextlib.contextmanager
    def _guarded(self) -> Iterator[None]:
        try:
            yield
        except OSError as error:
            self.failed = True
            self.writer.abandon(self.target)
            kept = self.writer.kept
            after = (f"it keeps the {kept:,} messages written before" if kept
                     else "nothing was recorded, the file is removed")
            raise CtlError(f"{self.target}: {error.strerror or error}; {after}",
                           Exit.NODE_FAILED) from None


class Progress:
    """Records, rate and losses so far, on stderr: the radio's from each stream's timer
    (counted as records come, on the steps before each alone), the gateway's from
    ``seq`` (every message of the node: :attr:`Message.gap`), apart from those missed
    while a base station was down (from the heartbeats: :class:`Losses`)."""

    def __init__(self, target: Path, terminal: bool) -> None:
        self.target = target
        self.terminal = terminal
        self.losses: Losses[None] = Losses(ahead=0)
        self.summary = Summary()
        self._shown = 0.0

    @property
    def records(self) -> int:
        return self.summary.received

    def count(self, message: Message) -> None:
        for counted in self.losses.add(message.node, message.record, message.payload, None):
            self.summary.add(counted, message.gap)

    def status(self, status: Status) -> None:
        """A heartbeat: when each base station was down, for the records after it."""
        self.losses.status(status.payload)

    def line(self, elapsed: float) -> str:
        rate = self.records / elapsed if elapsed > 0 else 0.0
        return (f"{PROG}: {self.target}: {self.records:,} records in {elapsed:.0f} s, "
                f"{rate:.1f}/s, {self.summary.line()}")

    def show(self, elapsed: float) -> None:
        every = PROGRESS_S if self.terminal else PROGRESS_PIPE_S
        if elapsed - self._shown < every:
            return
        self._shown = elapsed
        if self.terminal:
            sys.stderr.write("\r\x1b[K" + self.line(elapsed))
            sys.stderr.flush()
        else:
            print(self.line(elapsed), file=sys.stderr, flush=True)

    def done(self, elapsed: float) -> None:
        if self.terminal:
            sys.stderr.write("\r\x1b[K")
        print(self.line(elapsed) + " (finished)", file=sys.stderr, flush=True)
