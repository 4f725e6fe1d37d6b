"""What a recording says of each packet's way to the host, for the time refined after
the fact (:mod:`aspp.refine`): per node and power-up, each timed record's device time,
when its packet began to reach the host, and whether it waited on the serial line.

The records say the device time (and the ``time`` the live estimate gave). The rest
is in the ``serial`` channel, every read with the UNIX and monotonic times it was made:
the reads are decoded again here as the live reader decoded them
(:class:`gateway.daemon.station.reader.Reader`, which a replay feeds the same reads),
each reply's arrival is its read's monotonic time less its own bytes' time on the line,
and it waited (:func:`aspp.clock.waited`) if it began within the floor's noise of the
read that ended the packet or frame before it. Each record is matched to its packet
by the read it came in (its ``host_time`` is that read's ``log_time``), its node and
its command, in order: the daemon records a read before the records decoded from it.
Where a record was published when the line went quiet (the reader's idle timer), its
packet is resolved then, as live. A record whose packet is not found has no arrival
and takes no part.

A power-up ends where the live clock was reset: the node's timer restarted (its
``device_time`` then no longer counts its timer's ticks, whole wraps apart) or the
gateway's numbering began again (``seq`` went back: a new gateway, a new monotonic
origin perhaps).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from aspp import Ack, Decoder, Nack, PingOk, Reply
from aspp.clock import FLOOR_NOISE
from aspp.timing import TICKS_PER_SECOND, TIMER_MODULUS

from .files import is_serial_reads

IDLE = 0.030
"""Seconds of quiet that end what the line sent (base_station.idle_ms's default; a
recording does not say the one it was made with)."""
SEARCHED = 64
"""Packets of a node waiting for their records, at most (a node's records that were
never published, their packets not decoded into one: a bad record, are passed by)."""


@dataclass(frozen=True)
class LineSettings:
    """A base station's line as the recording's gateway had it (its metadata)."""

    byte_time: float
    """Seconds a byte takes on the line (10 bits at the baud rate)."""
    latency: float
    """base_station.latency_ms, in seconds: what ``time`` subtracts from the line."""


@dataclass(slots=True)
class _Packet:
    read: int
    command: int
    arrival: float
    waited: bool
    shift: float
    latency: float


@dataclass
class _Line:
    settings: LineSettings
    decoder: Decoder = field(default_factory=Decoder)
    free: float = math.inf
    """When the read was made that ended the last packet or frame (monotonic): infinite
    until one is read, as the live reader's after the port opened."""
    pending: tuple[int, float, float] | None = None
    """The read that left bytes in the decoder: (log_time ns, UNIX s, monotonic s)."""


@dataclass
class PowerUp:
    """One node's records between two resets of its clock, as :func:`aspp.refine.refine`
    takes them, with what converts its lines back to ``time``."""

    node: int
    device: list[float] = field(default_factory=list)
    arrival: list[float] = field(default_factory=list)
    """Monotonic seconds at which each packet began to reach the host."""
    waited: list[bool] = field(default_factory=list)
    live: list[float] = field(default_factory=list)
    """Each record's ``time`` on the monotonic clock, its read's conversion undone."""
    shift: list[float] = field(default_factory=list)
    """UNIX less monotonic at its read, less the line's latency: line + shift = time."""


Row = tuple[int, PowerUp | None, int]
"""A table's row: its message's log_time, and its power-up and place among its points
(None: not refined, an untimed record or one whose packet was not found)."""


class Sightings:
    """Fed a recording's messages in order (:meth:`feed`): the power-ups of its nodes,
    and for each topic the rows asked, in order (``rows``)."""

    def __init__(self, lines: dict[str, LineSettings], default: LineSettings) -> None:
        self._settings = lines
        self._default = default
        self._lines: dict[str, _Line] = {}
        self._packets: dict[int, deque[_Packet]] = {}
        self._current: dict[int, tuple[PowerUp, int, int]] = {}
        """Per node: its power-up, the ticks its device time is ahead of its timer
        (mod 2**32), and its last seq."""
        self.power_ups: list[PowerUp] = []
        self.rows: dict[str, list[Row]] = {}
        self.reads = 0
        """Serial reads met: none, and nothing can be refined."""

    def feed(self, topic: str, log_time: int, publish_time: int, data: bytes,
             payload: dict[str, Any] | None, kept: bool) -> None:
        """One message: a serial read (``data``), or a node's record (``payload``, a
        row asked for if ``kept``); others are passed over."""
        if payload is None:
            if is_serial_reads(topic):
                self._read(topic, log_time, data, publish_time / 1e9)
            return
        power_up, index = self._record(payload, log_time)
        if kept:
            self.rows.setdefault(topic, []).append((log_time, power_up, index))

    def _read(self, topic: str, stamp: int, data: bytes, monotonic: float) -> None:
        self.reads += 1
        line = self._lines.get(topic)
        if line is None:
            line = self._lines[topic] = _Line(self._settings.get(topic, self._default))
        if line.pending is not None:  # (a silence before this read: the reader's rule)
            quiet = monotonic - line.pending[2] - len(data) * line.settings.byte_time
            if quiet >= IDLE:
                self._idle(line)
            line.pending = None
        self._dispatch(line, line.decoder.feed(data), stamp, stamp / 1e9, monotonic)
        if line.decoder.pending:
            line.pending = (stamp, stamp / 1e9, monotonic)

    def _idle(self, line: _Line) -> None:
        read, line.pending = line.pending, None
        if read is not None:
            self._dispatch(line, line.decoder.line_idle(), *read)

    def _dispatch(self, line: _Line, events: list, stamp: int, unix: float,
                  monotonic: float) -> None:
        settings = line.settings
        for event in events:
            kind = type(event)
            if kind is Reply:
                arrival = monotonic - len(event.raw) * settings.byte_time
                packet = _Packet(stamp, event.command, arrival,
                                 arrival - line.free < FLOOR_NOISE,
                                 unix - monotonic - settings.latency, settings.latency)
                line.free = monotonic
                queue = self._packets.setdefault(event.node, deque(maxlen=SEARCHED))
                queue.append(packet)
            elif kind not in (Ack, Nack, PingOk):
                line.free = monotonic  # (a frame, or bytes that framed nothing)

    def _packet(self, node: int, stamp: int, command: Any) -> _Packet | None:
        """The packet a record of ``node`` came in, read at ``stamp``: the first such
        of its command, those before it passed by."""
        queue = self._packets.get(node, ())
        for i, packet in enumerate(queue):
            if packet.read == stamp and packet.command == command:
                for _ in range(i + 1):
                    found = queue.popleft()  # type: ignore[union-attr]
                return found
        return None

    def _record(self, payload: dict[str, Any], stamp: int) -> tuple[PowerUp | None, int]:
        node, device, timer = (payload.get(k) for k in ("node", "device_time", "timer"))
        live, seq = payload.get("time"), payload.get("seq")
        if not (isinstance(node, int) and _real(device) and _real(live)
                and isinstance(timer, int) and isinstance(seq, int)):
            return None, 0
        command = payload.get("command")
        packet = self._packet(node, stamp, command)
        if packet is None:  # (published when the line went quiet: resolved now)
            for line in self._lines.values():
                if line.pending is not None and line.pending[0] == stamp:
                    self._idle(line)
            packet = self._packet(node, stamp, command)
        if packet is None:
            return None, 0
        ahead = (round(device * TICKS_PER_SECOND) - timer) % TIMER_MODULUS
        current = self._current.get(node)
        if current is None or current[1] != ahead or seq <= current[2]:
            power_up = PowerUp(node)
            self.power_ups.append(power_up)
        else:
            power_up = current[0]
        self._current[node] = (power_up, ahead, seq)
        power_up.device.append(device)
        power_up.arrival.append(packet.arrival)
        power_up.waited.append(packet.waited)
        power_up.live.append(live - packet.shift)
        power_up.shift.append(packet.shift)
        return power_up, len(power_up.device) - 1


def _real(value: Any) -> bool:
    return isinstance(value, float | int) and not isinstance(value, bool) and math.isfinite(
        value)
