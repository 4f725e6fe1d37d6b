"""A recording played back in place of the base station: ``replay://PATH``.

It stands where :class:`~gateway.daemon.station.link.SerialLink` stands: each recorded read
goes to the reader with the times it was read at (UNIX and monotonic), so the reader,
the nodes' clock estimates and the publisher do exactly what they did live. It takes
nothing: a write is an error (the gateway sends nothing during a replay).

A file without serial reads (``gx2ctl record``'s: a subscriber never sees the bytes) is
played by publishing its messages again, each on its topic with its recorded payload;
the nodes are not fed, and the gateway's status says how far the replay is. What
decides is the file's first read or node record: the daemon records each read before
the records decoded from it, so a node record before any read is a subscriber's. The
recorded status messages (``gx2/gateway/status``) are not published again: the replaying
gateway publishes its own, and a subscriber must not take a recorded gateway for the
one it is listening to. Marks are published again from both kinds of file.

Pace: the recorded one divided by ``speed``; ``speed=0`` plays as fast as the gateway
takes it, letting the loop run other work every YIELD_EVERY reads. Playing starts
``delay`` seconds after the gateway does (the URL's options: :mod:`.replayurl`).

Which reads a base station plays: a file of several stations' reads (its
``gx2-gateway`` metadata names them) the channel of the station's own name, and a
station whose name it does not hold is refused at start (:meth:`Replay.nothing_to_play`);
a file of one station's reads its only channel, whatever the station replaying it is
called. Each read is played once the records the recording gateway published from it
have been read (the file holds them after it), so that a later file of a recording
starts each node's ``seq`` and ``device_time`` at the recorded ones
(:mod:`.replaystart`).

What cannot be read is skipped, with a line logged for each file not read whole (a
file among the others that is empty or not MCAP, a damaged chunk, a file cut short),
and the rest is played; a replay that skipped something is ``partial``, and a gateway
that exits when it is done (``exit=true``) then exits with status PARTIAL.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.common.topics import parse
from gateway.recording.files import (
    MARK,
    RecordingError,
    is_serial_reads,
    serial_channels,
)
from gateway.recording.reader import Entry
from gateway.recording.reports import FileReport

from .replayread import ReplayReader
from .replayurl import SCHEME, Replay, recorded_stations

if TYPE_CHECKING:
    from .replaystart import RecordedStart

log = logging.getLogger("gx2.replay")
YIELD_EVERY = 200
FILE_OF_READS = "serial"
"""A gateway's recording (its serial reads): played by reading them again."""
FILE_OF_MESSAGES = "published"
"""A file of published messages (no serial reads): played by publishing them again."""


class ReplayLink:
    """Plays the ``serial`` channel of a recording into ``on_data``; the messages of a
    file without one, and the marks of every file, into ``on_message``."""

    def __init__(self, replay: Replay, on_data: Callable[[bytes, float, float], None],
                 on_state: Callable[[bool], None], on_end: Callable[[], None],
                 on_message: Callable[[str, dict[str, Any]], object], *,
                 station: str = "", marks: bool = True,
                 start: RecordedStart | None = None,
                 source: ReplayReader | None = None) -> None:
        self.replay = replay
        self._source = source or ReplayReader(replay.files, replay.span)
        """The reading of the recording it shares with the other stations playing it
        (:mod:`.replayread`): each file read and decompressed once for all."""
        self._several: dict[Path, tuple[str, ...]] = {}
        """Each file's stations, as its head names them (read once)."""
        self.start_at = start
        """Given the recorded records, to start each node's seq and device time at the
        recorded ones."""
        self._origin: tuple[float, float] | None = None
        """(recorded, loop) time of the first thing played: the pace's origin."""
        self.station = station
        """The name of the base station it plays: a file of several stations' reads is
        played from that one's channel (``serial/<station>``), a file of one station's
        from its only one, whatever that station was called."""
        self.marks = marks
        """Whether it publishes the recording's marks again (one station of several)."""
        self.port = f"{SCHEME}{replay.files[0]}"
        self._on_data = on_data
        self._on_state = on_state
        self._on_end = on_end
        self._on_message = on_message
        self._task: asyncio.Task[None] | None = None
        self.up = False
        self.since = time.time()
        self.reconnects = 0
        self.bytes_read = 0
        self.reads = 0
        """What has been played: serial reads, and messages published again (status
        shows it as the replay's progress)."""
        self.messages = 0
        """Messages published again (of them)."""
        self.unreadable = 0
        """Messages that are not the JSON objects their channel holds: skipped."""
        self.last_error = ""
        self.finished = False
        self.reopening = False
        self.unsent = 0
        self.partial = False
        """Something unreadable was skipped (a line says what)."""

    @property
    def state(self) -> str:
        """``up`` while it plays (and after), ``down`` once closed: as a port's link."""
        return "up" if self.up else "down"

    def start(self) -> None:
        self._source.join(self, self._plays, self._read_file)
        self.up = True
        self.since = time.time()
        self._on_state(True)
        self._task = asyncio.get_running_loop().create_task(self._play())
        self._task.add_done_callback(self._played)

    def _played(self, task: asyncio.Task[None]) -> None:
        """The play ended. Ended by an error (a bug), it must still end as a replay
        does: said in a line, its place in the shared reading left (else the reading
        waits on its full queue, and every other station with it), and the end handled
        (else a replay with exit=true never exits): partial, as a file not read whole."""
        if task.cancelled() or task.exception() is None:
            return
        error = task.exception()
        self.last_error = f"the replay stopped: {type(error).__name__}: {error}"
        log.error("replay: %s (a bug: please report it)", self.last_error)
        self.partial = True
        self.finished = True
        self._source.leave(self)
        self._on_end()

    def write(self, data: bytes) -> None:
        raise OSError("replaying a recording: nothing is sent to the base station")

    def _plays(self, path: Path) -> bool:
        """Whether it plays ``path``: a file of one station's reads (or none), or of
        several stations' that holds its own (the others' are skipped: _not_its_own)."""
        several = self._stations_of(path)
        return not several or self.station in several

    def _stations_of(self, path: Path) -> tuple[str, ...]:
        several = self._several.get(path)
        if several is None:
            several = self._several[path] = recorded_stations(path)
        return several

    async def _play(self) -> None:
        speed = self.replay.speed
        seen = 0
        await asyncio.sleep(self.replay.delay)
        for path in self.replay.files:
            # FILE_OF_READS (a gateway's recording) or FILE_OF_MESSAGES, once the file
            # has shown which
            kind: str | None = None
            several = self._stations_of(path)
            if not self._plays(path):
                self._not_its_own(path, several)
                continue
            # the channel of reads it plays: with one station's, the first one found
            channel = serial_channels(self.station)[0] if several else None
            # a read, and the marks after it, are played once the records recorded
            # after it have been seen: at the next read of the channel (.replaystart)
            ahead: list[tuple[Entry, bool]] = []
            async for entry in self._source.entries(self, path):
                seen += 1
                if speed == 0 and seen % YIELD_EVERY == 0:
                    await asyncio.sleep(0)
                topic = entry.topic
                if channel is None and is_serial_reads(topic):
                    channel = topic
                serial = topic == channel
                record = not serial and parse(topic) is not None
                if kind is None and (record or is_serial_reads(topic)):
                    # (a gateway's recording of several stations: any station's reads)
                    kind = FILE_OF_READS if is_serial_reads(topic) else FILE_OF_MESSAGES
                start = self.start_at
                if record and kind == FILE_OF_READS and start is not None and start.waiting:
                    start.recorded(entry)
                played = ((topic == MARK and self.marks) or (serial and kind == FILE_OF_READS)
                          or (record and kind == FILE_OF_MESSAGES and self.marks))
                if not played:
                    continue
                if serial or kind != FILE_OF_READS:
                    await self._play_paced(ahead)
                ahead.append((entry, serial))
            await self._play_paced(ahead)
        self.partial = self.partial or self.unreadable > 0
        self.finished = True
        self._source.leave(self)
        if self.unreadable:
            log.warning("replay: skipped %d messages that are not JSON objects",
                        self.unreadable)
        log.info("replay finished: %d reads (%d bytes), %d messages published again, from "
                 "%d file%s%s", self.reads - self.messages, self.bytes_read, self.messages,
                 len(self.replay.files), "" if len(self.replay.files) == 1 else "s",
                 " (partial: what could not be read was skipped)" if self.partial else "")
        self._on_end()

    async def _play_paced(self, entries: list[tuple[Entry, bool]]) -> None:
        """Play ``entries`` (and empty the list), each at its recorded time over speed."""
        speed = self.replay.speed
        for entry, serial in entries:
            if speed > 0:
                loop = asyncio.get_running_loop()
                host_time = entry.log_time / 1e9
                if self._origin is None:
                    self._origin = (host_time, loop.time())
                delay = self._origin[1] + (host_time - self._origin[0]) / speed - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)
            self._play_one(entry, serial)
        entries.clear()

    def _play_one(self, entry: Entry, serial: bool) -> None:
        if serial:
            self.reads += 1
            self.bytes_read += len(entry.data)
            self._on_data(entry.data, entry.log_time / 1e9,
                          (entry.publish_time or entry.log_time) / 1e9)
            return
        try:
            payload = entry.payload()
        except RecordingError:
            self.unreadable += 1
            return
        self.reads += 1
        self.messages += 1
        self._on_message(entry.topic, payload)

    def _not_its_own(self, path: Path, several: tuple[str, ...]) -> None:
        """A file of other stations' reads among the recording's (one that came after
        the gateway's check): skipped, as a file that cannot be read is."""
        line = (f"{path}: skipped: it holds the reads of base stations "
                f"{', '.join(several)}, none named {self.station!r}")
        log.warning("replay: %s", line)
        self.partial = True
        self.last_error = line

    def _read_file(self, report: FileReport) -> None:
        """A line as each file is done, if it was not read whole."""
        line = report.line()
        if line:
            log.warning("replay: %s", line)
        if report.partial:
            self.partial = True
            self.last_error = line

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        self._source.leave(self)
        self.up = False
