"""Samples lost, as the published records show them: counted from a node's timer and
from ``seq``, for export, plot and ``gx2ctl record`` alike (pure: no daemon, no I/O).

What each reveals (docs/interface.md, section 4):

- the **timer** (``device_time``, the timer unwrapped) steps by exactly one sample
  period between two records of a stream, so a longer step is samples that never
  arrived, whatever lost them: the radio, or the gateway;
- ``seq`` counts the messages the gateway published for the node (every record), so a
  gap in it is messages lost between the gateway and the reader (ZeroMQ, a slow
  subscriber, a recorder that could not keep up); a sample the radio lost never became
  a message, and never shows in ``seq``.

A sample missing from both is the gateway's: the radio's losses of a stream are what
its timer misses beyond its ``seq`` gaps.

The period is learned from the stream, as the gateway learns it (:mod:`gateway.daemon.
nodes`): the shortest step among the WINDOW steps either side, in periods of the
51,200 Hz clock. That step is a stream's period only if it is also its most common one
(at any loss rate below 100% a stream steps by one period more often than by any other
count of them) and a divider the node can have (MIN_DIVIDER..MAX_DIVIDER, about 3 ms to
1 s); records polled now and then step irregularly, or by more than a second, and lose
nothing. A step shorter than MIN_DIVIDER clocks (a record polled in a stream's cycle)
is not a stream's step and loses nothing either.

A step is not counted (the count is unknown: None) where the timer restarted, that is
where ``device_time`` and the raw ``timer`` no longer step alike (the gateway carries
``device_time`` on by the host's clock over a reboot: :class:`aspp.timing.
TimerUnwrapper`) or ``device_time`` goes back, and where ``seq`` does not go up (the
gateway restarted): the first row after a reboot says so. A continuous-mode reply
(``continuous_mode``, the node's answer to a start or a stop) after a stream's silence
is where it begins again: its next row is counted from that cycle, not from the row
before (a stream stopped in between lost nothing), unless the timer restarted before
it (a reboot, then a start: what the stream lost before is not known).

Where a reader skipped a damaged stretch of a recording (:meth:`Losses.unread`), what
each stream misses across it was recorded but could not be read: neither the radio's
nor the gateway's loss, it is counted apart (``unread``), and said as the file's.

Where a stream's step spans an outage of its node's base station (unplugged, its port
lost: :mod:`.outages`, from the gateway's status messages fed in with
:meth:`Losses.status`), the samples that fell due from its row before the outage until
the station was back were missed by no radio: they are counted apart (``down``), as the
gateway counts them (its status's ``lost_station_down``), and any after it are the
radio's.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any, Generic, NamedTuple, TypeVar

from aspp.timing import (
    CLOCK_HZ,
    MAX_DIVIDER,
    MIN_DIVIDER,
    TICKS_PER_CLOCK,
    TICKS_PER_SECOND,
    TIMER_MODULUS,
)

from .outages import Outages

T = TypeVar("T")
WINDOW = 32
"""Steps either side of a row among which the stream's period is looked for: enough that
a one-period step is among them at any loss a stream survives (at 26% loss, the chance
that 64 steps in a row are all longer is 0.26 ** 64)."""
STARTED = "continuous_mode"
"""The record a node answers a start (or a long-form stop) with: its streams begin again."""
STOPPED_PERIODS = 5
"""Sample periods a stream is silent before a continuous-mode reply that starts it
afresh: a stop is confirmed by five silent periods (aspp.stop), and a start retried
amid the stream comes within a period or two of its last record (five samples lost in
a row before it, at 26% loss, one time in 840)."""


class Counted(NamedTuple, Generic[T]):
    """A row with what is missing just before it."""

    item: T
    lost: int | None
    """Samples of the stream missing just before this row, by the timer; None: unknown
    (no timer, the first row seen, the first after a reboot or a gateway restart)."""
    gateway: int
    """Of ``lost``, the samples that are missing from ``seq`` too (the node's messages
    missing by ``seq`` since the stream's previous row, at most ``lost``): the
    gateway's losses, not the radio's."""
    unread: int = 0
    """Of ``lost``, the samples in a stretch of the recording that could not be read
    (all of ``lost``, for the first row after it; the others 0)."""
    down: int = 0
    """Of ``lost``, the samples that fell due while the node's base station was down."""

    @property
    def radio(self) -> int:
        """Of ``lost``, the samples the radio lost."""
        return max(0, (self.lost or 0) - self.gateway - self.unread - self.down)


class _Row(NamedTuple, Generic[T]):
    item: T
    step: int | None
    """Clocks (51,200 Hz) since the stream's previous row: its steps; None: not a step
    of the stream (see :class:`Stream`)."""
    lost: int | None
    """Decided already (a first row, a restart, a short step), or None to decide."""
    gateway: int
    """The node's messages missing by ``seq`` since the stream's previous row."""
    unread: bool = False
    """A stretch of the recording that could not be read lies before it."""
    span: tuple[float, float] | None = None
    """The UNIX times of the stream's previous row and of this one, if both have one."""


class _Last(NamedTuple):
    ticks: int
    timer: int | None
    seq: int | None
    count: int
    time: float | None
    """When (UNIX s, the records' clock), to hold against a station's outages."""


class Stream(Generic[T]):
    """One node's one record, a row at a time: each row is decided once ``ahead`` more
    rows of its stream are in (0: at once, on the steps before it alone). ``outage``:
    when its node's base station came back from an outage between two UNIX times (its
    last, if several), or None: there was none (:meth:`.Outages.back`)."""

    def __init__(self, ahead: int = WINDOW,
                 outage: Callable[[float, float], float | None] | None = None) -> None:
        self.ahead = ahead
        self._outage = outage
        self.period: int | None = None
        """The stream's period (clocks) at the last row decided, if it is a stream."""
        self._last: _Last | None = None
        """The stream's last row, or the node's continuous-mode reply since."""
        self._unknown = False
        """The timer restarted before a continuous-mode reply: the next row says so."""
        self._replied = False
        """The node sent a continuous-mode reply amid its stream since the last row (a
        stop's, it may be)."""
        self._unread = False
        """A stretch of the recording was skipped unread: the next row's losses lie in it."""
        self._pending: deque[_Row[T]] = deque()
        self._behind: deque[int] = deque()
        self._window: dict[int, int] = {}
        """How often each step occurs among the pending rows and up to WINDOW decided."""

    def started(self, payload: Mapping[str, Any], count: int) -> None:
        """The node's continuous-mode reply (a start or a stop). After a silence (a
        stream stopped: see STOPPED_PERIODS) its stream begins at that cycle, so its
        next row is counted from there, not from the last one: nothing was lost in
        between. Amid the stream (a start retried, its first reply lost) it changes
        nothing. A timer that restarted before it (a reboot, then a start) is still
        said by the next row. A silence across an outage of its station is no stop
        unless a reply (a stop's) came before it: a node streams on while its base
        station is down, and the gateway starts it again when it is back, whose reply
        may come before the stream's first record (a slow stream)."""
        start = _last(payload, count)
        if start is None:
            return
        last = self._last
        if last is not None and _restarted(last, start.ticks, start.timer, start.seq):
            self._unknown = True
        elif last is not None and not self._silent(last, start):
            self._replied = True
            return
        elif last is not None and not self._replied and self._spans_outage(last, start):
            return
        self._last = start

    def _silent(self, last: _Last, start: _Last) -> bool:
        """Whether the stream sent nothing for STOPPED_PERIODS before ``start`` (or
        has no period yet to tell)."""
        period = self.period or min(self._window, default=None)
        return period is None or (
            start.ticks - last.ticks >= STOPPED_PERIODS * period * TICKS_PER_CLOCK)

    def _spans_outage(self, last: _Last, start: _Last) -> bool:
        """Whether its node's station was down between ``last`` and ``start``."""
        return (self._outage is not None and last.time is not None
                and start.time is not None and self._outage(last.time, start.time) is not None)

    def add(self, payload: Mapping[str, Any], item: T, count: int = 0) -> list[Counted[T]]:
        """Add the next row (``count``: the node's messages so far, this one included);
        return the rows decided now, in order."""
        new = _last(payload, count)
        if new is None:
            return [Counted(item, None, 0)]
        ticks, timer, seq = new.ticks, new.timer, new.seq
        last, self._last = self._last, new
        self._replied = False
        unread, self._unread = self._unread, False
        restarted = self._unknown or (last is not None and _restarted(last, ticks, timer, seq))
        self._unknown = False
        if last is None or restarted:
            out = self.flush()
            self._behind.clear()
            self._window.clear()
            out.append(Counted(item, None, 0))
            return out
        gateway = _seq_missing(last, seq, count)
        step = round((ticks - last.ticks) / TICKS_PER_CLOCK)
        if step < MIN_DIVIDER:
            self._pending.append(_Row(item, None, 0, 0))
        else:
            span = None if last.time is None or new.time is None else (last.time, new.time)
            self._pending.append(_Row(item, step, None, gateway, unread, span))
            self._window[step] = self._window.get(step, 0) + 1
        out = []
        while len(self._pending) > self.ahead:
            out.append(self._decide())
        return out

    def unread(self) -> None:
        """A stretch of the recording was skipped unread: what the next row misses was
        in it (recorded, not lost by the radio or the gateway)."""
        self._unread = True

    @property
    def seconds(self) -> float | None:
        """Seconds between samples of the stream, if it is one."""
        return None if self.period is None else self.period / CLOCK_HZ

    def flush(self) -> list[Counted[T]]:
        """Decide every row still waiting (the end, or the stream begins again)."""
        return [self._decide() for _ in range(len(self._pending))]

    def _decide(self) -> Counted[T]:
        row = self._pending.popleft()
        if row.step is None:
            return Counted(row.item, row.lost, row.gateway)
        period = self._period()
        self.period = period
        lost = 0 if period is None else max(0, round(row.step / period) - 1)
        self._behind.append(row.step)
        if len(self._behind) > WINDOW:
            old = self._behind.popleft()
            left = self._window[old] - 1
            if left:
                self._window[old] = left
            else:
                del self._window[old]
        if row.unread:  # what it misses was recorded: the file lost it, not the gateway
            return Counted(row.item, lost, 0, lost)
        gateway = min(lost, row.gateway)
        return Counted(row.item, lost, gateway, 0, self._down(row.span, lost - gateway))

    def _down(self, span: tuple[float, float] | None, lost: int) -> int:
        """Of the ``lost`` samples of a step over ``span``, those that fell due from its
        start until its node's station came back from an outage in it."""
        if not lost or span is None or self._outage is None or self.period is None:
            return 0
        back = self._outage(*span)
        if back is None:
            return 0
        # as the gateway counts lost_station_down: the samples due before the moment
        # the station was back, k periods after the step's start for k = 1, 2, ...
        due = math.ceil((back - span[0]) * CLOCK_HZ / self.period) - 1
        return max(0, min(lost, due))

    def _period(self) -> int | None:
        """The shortest step around the row being decided, if it is a stream's period."""
        window = self._window
        shortest = min(window)
        if shortest > MAX_DIVIDER or window[shortest] < max(window.values()):
            return None
        return shortest


class Losses(Generic[T]):
    """Every node's streams: feed it every message of a recording (or a subscription)
    in order, each record of a node under its own stream."""

    def __init__(self, ahead: int = WINDOW) -> None:
        self.ahead = ahead
        self.streams: dict[tuple[int, str], Stream[T]] = {}
        self._counts: dict[int, int] = {}
        self._started: dict[int, tuple[Mapping[str, Any], int]] = {}
        """Each node's last continuous-mode reply: where a stream first seen begins."""
        self.outages = Outages()

    def add(self, node: int, record: str, payload: Mapping[str, Any],
            item: T) -> list[Counted[T]]:
        """The rows decided now (this one's stream's, in order)."""
        count = self._counts[node] = self._counts.get(node, 0) + 1
        stream = self.streams.get((node, record))
        if stream is None:
            stream = self.streams[(node, record)] = Stream(
                self.ahead, lambda after, at: self.outages.back(node, after, at))
            if node in self._started:
                stream.started(*self._started[node])
        out = stream.add(payload, item, count)
        if record == STARTED:
            self._started[node] = (payload, count)
            for (owner, _), other in self.streams.items():
                if owner == node:
                    other.started(payload, count)
        return out

    def status(self, payload: Mapping[str, Any]) -> None:
        """A status message of the gateway (``gx2/gateway/status``), in its place among
        the records: when each base station was down."""
        self.outages.status(payload)

    def unread(self) -> None:
        """A stretch of the recording was skipped unread (a damaged chunk): each
        stream's next row misses what was in it."""
        for stream in self.streams.values():
            stream.unread()

    def finish(self) -> list[Counted[T]]:
        """The rows still waiting, decided on what came."""
        return [counted for stream in self.streams.values() for counted in stream.flush()]

    def period(self, node: int, record: str) -> float | None:
        """Seconds between samples of the stream, if it is one."""
        stream = self.streams.get((node, record))
        return None if stream is None else stream.seconds


def _last(payload: Mapping[str, Any], count: int) -> _Last | None:
    """Where ``payload`` is on the node's timer (None: it has no device time)."""
    device = payload.get("device_time")
    if not isinstance(device, (int, float)) or isinstance(device, bool) or device != device:
        return None
    return _Last(round(device * TICKS_PER_SECOND), _integer(payload.get("timer")),
                 _integer(payload.get("seq")), count, _time(payload))


def _time(payload: Mapping[str, Any]) -> float | None:
    """When the record was sampled (else read), UNIX s; None if it says neither."""
    for key in ("time", "host_time"):
        value = payload.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value == value:
            return float(value)
    return None


def _integer(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _restarted(last: _Last, ticks: int, timer: int | None, seq: int | None) -> bool:
    """Whether the timer restarted (a reboot) or the gateway did, since ``last``."""
    if ticks < last.ticks or (seq is not None and last.seq is not None and seq <= last.seq):
        return True
    if timer is None or last.timer is None:
        return False
    # the unwrapped time steps with the timer, modulo its wraps, unless the gateway
    # carried it on by the host's clock over a restarted timer; one clock period of
    # slack covers a device_time rounded to fewer digits than a double's
    apart = (ticks - last.ticks - (timer - last.timer)) % TIMER_MODULUS
    return min(apart, TIMER_MODULUS - apart) > TICKS_PER_CLOCK


def _seq_missing(last: _Last, seq: int | None, count: int) -> int:
    """Messages of the node missing by ``seq`` between ``last`` and this row: how far
    ``seq`` went, less the messages of the node that came in between."""
    if seq is None or last.seq is None or seq <= last.seq:
        return 0
    return max(0, (seq - last.seq) - (count - last.count))


__all__ = ["STARTED", "WINDOW", "Counted", "Losses", "Stream"]
