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
``delay`` seconds after the gateway does (default DELAY_S): a PUB socket drops what it
publishes before a subscriber has connected, and a subscriber started with the gateway
needs a moment to.

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
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs

from mcap.records import Header, Metadata
from mcap.stream_reader import StreamReader

from gateway.common.topics import parse
from gateway.recording.files import (
    MARK,
    METADATA,
    RecordingError,
    is_serial_reads,
    serial_channels,
    usable_files,
)
from gateway.recording.reader import Entry, read
from gateway.recording.reports import FileReport, Reading

from .replayread import ReplayReader

if TYPE_CHECKING:
    from .replaystart import RecordedStart

log = logging.getLogger("gx2.replay")
SCHEME = "replay://"
YIELD_EVERY = 200
DELAY_S = 1.0
OPTIONS = ("speed", "exit", "delay", "from", "to", "between", "trial")
WINDOW_OPTIONS = ("from", "to", "between", "trial")
NOT_FILTERED = ("node", "record")
"""Export's other window options, which a replay does not take: the serial reads it
plays are not one node's each but the line's bytes, parsed by the gateway as live."""
"""A window of the recording, as gx2ctl export's --from, --to, --between-marks (here
``between=START,STOP``) and --trial take it (:mod:`gateway.recording.window`)."""
FILE_OF_READS = "serial"
"""A gateway's recording (its serial reads): played by reading them again."""
FILE_OF_MESSAGES = "published"
"""A file of published messages (no serial reads): played by publishing them again."""


@dataclass(frozen=True)
class Replay:
    """What a ``replay://PATH[?speed=N&exit=true&delay=S&from=..&to=..]`` URL asks for."""

    files: tuple[Path, ...]
    speed: float = 1.0
    exit: bool = False
    delay: float = DELAY_S
    span: tuple[int, int] | None = None
    """The window played (log_time ns, end excluded); None: all of it."""

    @classmethod
    def from_url(cls, url: str) -> Replay:
        """ValueError (one line) for a URL that cannot be played."""
        body = url[len(SCHEME):]
        path, _, query = body.partition("?")
        if not path:
            raise ValueError(f"{url!r} names no recording: replay://PATH[?speed=N&exit=true]")
        try:
            options = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
        except ValueError:
            raise ValueError(f"{url!r}: the query is not name=value pairs") from None
        unknown = sorted(set(options) - set(OPTIONS))
        if set(unknown) & set(NOT_FILTERED):
            raise ValueError(f"{url!r}: a replay has no {'/'.join(NOT_FILTERED)} keys: it "
                             "plays the base station's serial reads, of every node, and "
                             "the gateway publishes the nodes its configuration lists "
                             "(list only those under nodes:)")
        if unknown:
            raise ValueError(f"{url!r}: unknown option {unknown[0]!r} "
                             f"({', '.join(OPTIONS)})")
        speed = _number(url, options, "speed", 1.0, 1e6, "0: as fast as possible")
        delay = _number(url, options, "delay", DELAY_S, 3600, "seconds before playing")
        leave = False
        if "exit" in options:
            text = options["exit"][-1].lower()
            if text not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"{url!r}: exit must be true or false, not {text!r}")
            leave = text in ("true", "1", "yes")
        try:
            files = usable_files([path])
        except RecordingError as error:
            raise ValueError(str(error)) from None
        span = None
        if any(name in options for name in WINDOW_OPTIONS):
            files, span = _window(url, files, options)
        return cls(tuple(files), speed, leave, delay, span)

    def nothing_to_play(self, station: str | None) -> str:
        """Why the recording has nothing to play for the base station named ``station``
        (None: the one-station form's, which has no name to give it) (empty if it has):
        a file of several stations' reads holds none of its name, or
        no file holds a serial read, a node's record or a mark. Files are read only up
        to the first such message, so a gateway's recording is judged by its first
        chunk (and each file's head, where its stations are named)."""
        for path in self.files:
            several = recorded_stations(path)
            if several and station is None:
                return (f"{path} holds the reads of base stations {', '.join(several)}: "
                        "replay it under base_stations:, each station named as one of "
                        "them (see docs/recording.md, Recording and replay)")
            if several and station not in several:
                return (f"{path} holds the reads of base stations {', '.join(several)}, "
                        f"none named {station!r}: name the base station that replays it "
                        "as one of them")
        for path in self.files:
            if any(_playable(entry.topic) for entry in read(path, Reading())):
                return ""
        where = self.files[0] if len(self.files) == 1 else f"{len(self.files)} files"
        return (f"{where}: nothing to replay: no serial reads (a gateway's recording) and no "
                "published records or marks (gx2ctl record's)")


def recorded_stations(path: Path) -> tuple[str, ...]:
    """The names of the base stations whose reads a file of several holds, each on its
    own channel (``serial/<name>``), as the gateway that wrote it said in the file's
    head (its ``gx2-gateway`` metadata); none for a file of one station's reads
    (``serial``, whatever that station was called), of none, or of another program."""
    try:
        with path.open("rb") as stream:
            for record in StreamReader(stream, emit_chunks=True).records:
                if isinstance(record, Metadata) and record.name == METADATA:
                    names = json.loads(record.metadata.get("stations", "[]"))
                    return tuple(str(station["name"]) for station in names)
                if not isinstance(record, Header):
                    break  # (the gateway writes its metadata first)
    except Exception:  # a head that does not read names no stations: what cannot be
        pass  # read is said when the file is played
    return ()


def _window(url: str, files: list[Path], options: dict[str, list[str]]
            ) -> tuple[list[Path], tuple[int, int] | None]:
    """The files a URL's window touches, and its span; ValueError (one line) for a
    window that cannot be taken, or trials between marks with none picked."""
    from gateway.recording.catalogue import catalogue
    from gateway.recording.window import Asked, WindowError, touched, windows

    def last(name: str) -> str | None:
        return options[name][-1] if name in options else None

    between = None
    if (text := last("between")) is not None:
        start, _, stop = text.partition(",")
        if not start or not stop:
            raise ValueError(f"{url!r}: between must be START,STOP (the texts of two marks)")
        between = (start, stop)
    trial = None
    if (text := last("trial")) is not None:
        if not text.isdecimal() or int(text) < 1:
            raise ValueError(f"{url!r}: trial must be a number from 1, not {text!r}")
        trial = int(text)
    asked = Asked(_time(last("from")), _time(last("to")), between, trial,
                  names=WINDOW_OPTIONS)
    described = catalogue(files, whole=asked.marked)
    try:
        found = windows(asked, described)
    except WindowError as error:
        raise ValueError(f"{url!r}: {error}") from None
    if len(found) > 1:
        raise ValueError(f"{url!r}: {len(found)} trials between those marks: pick one "
                         "with trial=N")
    return [d.path for d in touched(described, found[0])], found[0].span


def _time(text: str | None) -> str | None:
    """A ``from``/``to`` as written: a URL's query reads ``+`` as a space, and in a date
    a space before its zone's offset can only have been one (12:06:45+01:00)."""
    from gateway.recording.window import dated
    return text.replace(" ", "+") if text is not None and dated(text) else text


def _playable(topic: str) -> bool:
    return is_serial_reads(topic) or topic == MARK or parse(topic) is not None


def _number(url: str, options: dict[str, list[str]], name: str, default: float,
            most: float, meaning: str) -> float:
    if name not in options:
        return default
    text = options[name][-1]
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value <= most:
        raise ValueError(f"{url!r}: {name} must be a number from 0 to {most:g} ({meaning}), "
                         f"not {text!r}")
    return value


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
