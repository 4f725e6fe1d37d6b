"""Recordings on disk: MCAP files, their names and channels, the framing both the
writer (:mod:`.writer`) and the reader (:mod:`.reader`) rely on, and finding them.

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
import fcntl
import math
import struct
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

from mcap.opcode import Opcode

from gateway.common.reading import number
from gateway.common.topics import MARK_TOPIC, STATUS_TOPIC

SERIAL_READS = "serial"
"""The channel of the serial reads of a gateway of one base station."""
WRITTEN = "serial/written"


def serial_channels(station: str | None) -> tuple[str, str]:
    """A station's two serial channels, (reads, writes): ``serial`` and ``serial/written``
    for a gateway of one base station (``station`` None), ``serial/<station>`` and
    ``serial/<station>/written`` for each of several."""
    if station is None:
        return SERIAL_READS, WRITTEN
    return f"{SERIAL_READS}/{station}", f"{SERIAL_READS}/{station}/written"


def is_serial_reads(topic: str) -> bool:
    """Whether ``topic`` is a channel of serial reads (one station's or the only one's)."""
    return topic == SERIAL_READS or (topic.startswith(SERIAL_READS + "/") and topic != WRITTEN
                               and not topic.endswith("/written"))
METADATA = "gx2-gateway"
"""The name of the metadata record a file opens with: what wrote it (the gateway's
says its version, port and nodes, and with several base stations their names)."""
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


class OutOfRange(ValueError):
    """A time no MCAP timestamp can hold: one line saying which."""


NS_LIMIT = 2.0 ** 64
"""An MCAP timestamp is an unsigned 64-bit count of nanoseconds (to the year 2554)."""


def ns(seconds: float) -> int:
    """``seconds`` as an MCAP timestamp; OutOfRange for a time none can hold (negative,
    not finite, or one already in nanoseconds: a foreign recording's ``time``), found
    here before the writer has taken any of the message."""
    if not math.isfinite(seconds) or not 0 <= seconds * 1e9 < NS_LIMIT:
        raise OutOfRange(f"time {seconds:g} s is outside what a recording holds "
                         "(0 to 1.8e10 s: seconds since 1970)")
    return round(seconds * 1e9)


def message_times(payload: Mapping[str, Any]) -> tuple[float, float]:
    """A published message's (logged, sampled) UNIX times: when it was read (a record's
    ``host_time``; a status's ``gateway.time``; now, for a message with neither), and
    when its sample was taken (``time``; else when it was read). The recording's
    log_time and publish_time, and the live view's message time. A time that is no
    finite float (NaN, text, an integer too large for one) is taken as absent."""
    logged = payload.get("host_time")
    if logged is None:
        gateway = payload.get("gateway")
        logged = gateway.get("time") if isinstance(gateway, Mapping) else None
    logged = number(logged)
    if logged is None:
        logged = time.time()
    sampled = number(payload.get("time"))
    return logged, logged if sampled is None else sampled


MAGIC = b"\x89MCAP0\r\n"
MARK = MARK_TOPIC.decode()
"""The channel of marks (``gx2ctl mark``), each a JSON object (see MARK_TOPIC)."""
STATUS = STATUS_TOPIC.decode()
"""The channel of the gateway's status (its heartbeat), each a JSON object."""
PARTIAL = 1
"""Exit status of export, plot, and a replay with ``exit=true``, that skipped something
unreadable (a file, a damaged chunk) and read the rest."""
RECORD_HEAD = struct.Struct("<BQ")
END = (RECORD_HEAD.pack(Opcode.DATA_END, 4) + bytes(4)
        + RECORD_HEAD.pack(Opcode.FOOTER, 20) + bytes(20) + MAGIC)
"""A data end (no CRC) and a footer saying there is no summary: a file's end."""
MESSAGE_HEAD = struct.Struct("<HIQQ")
CHUNK_HEAD = struct.Struct("<QQQII")
FOOTER_BYTES = RECORD_HEAD.size + 20 + len(MAGIC)
PRIVATE_OPCODES = 0x80
"""Opcodes from here on are for any writer's own records, skipped by their length."""
_OPCODES = frozenset(int(opcode) for opcode in Opcode)


def known_opcode(opcode: int) -> bool:
    """An opcode a record can have: where another is found, the framing is broken."""
    return opcode >= PRIVATE_OPCODES or opcode in _OPCODES

SCAN_BYTES = 1 << 20
LARGEST_CHUNK = 1 << 30
"""A chunk said to be larger is damaged (ours close at CHUNK_BYTES): not decompressed."""


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


def claim(output: IO[bytes]) -> None:
    """Say a file is being written: an advisory lock (flock) held while the writer has
    it open, which the system releases however the writer ends (a killed writer's file
    is not taken for one being written). Nothing for an output that is no file."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        fcntl.flock(output.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def being_written(path: Path) -> bool:
    """Whether a writer holds ``path`` open (its claim, above)."""
    try:
        with path.open("rb") as stream:
            fcntl.flock(stream.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False


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
