"""What a ``replay://PATH[?speed=N&exit=true&delay=S&from=..&to=..]`` URL asks for
(:class:`Replay`), and whether the recording has anything to play for a base station:
all a configuration's check needs, apart from the playing itself
(:mod:`gateway.daemon.station.replay`), so that checking a port's URL
(:mod:`.ports`) imports nothing of a running station.

Pace: the recorded one divided by ``speed``; ``speed=0`` plays as fast as the gateway
takes it. Playing starts ``delay`` seconds after the gateway does (default DELAY_S): a
PUB socket drops what it publishes before a subscriber has connected, and a subscriber
started with the gateway needs a moment to. ``from``, ``to``, ``between`` and ``trial``
play a window of the recording, as gx2ctl export takes one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs

from mcap.records import Header, Metadata
from mcap.stream_reader import StreamReader

from gateway.common.topics import parse
from gateway.recording.files import (
    MARK,
    METADATA,
    RecordingError,
    is_serial_reads,
    usable_files,
)
from gateway.recording.reader import read
from gateway.recording.reports import Reading

SCHEME = "replay://"
DELAY_S = 1.0
OPTIONS = ("speed", "exit", "delay", "from", "to", "between", "trial")
WINDOW_OPTIONS = ("from", "to", "between", "trial")
"""A window of the recording, as gx2ctl export's --from, --to, --between-marks (here
``between=START,STOP``) and --trial take it (:mod:`gateway.recording.window`)."""
NOT_FILTERED = ("node", "record")
"""Export's other window options, which a replay does not take: the serial reads it
plays are not one node's each but the line's bytes, parsed by the gateway as live."""


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
