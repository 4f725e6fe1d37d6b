"""Time on a node: its calculation cycle (the data rate) and its timer, with the
unwrapping that turns the timer into a device time that never goes back.

The one home of the protocol's time arithmetic. A node's calculation cycle is
``divider / 51200`` s, the divider living in EEPROM 0xFCA2 within 170..51200 (about
301 Hz down to 1 Hz); in continuous mode it sends one record a cycle.

The timer is a u32 counting 19,660,800 Hz since power-up; it wraps every 218.45 s. Fed
in order, consecutive readings less than one wrap apart unwrap exactly. A node silent
for longer (out of range, a lost stream) can hide whole wraps: given the host's clock
at each reading, :class:`TimerUnwrapper` counts the wraps the elapsed host time needs,
and when the timer cannot be reconciled with the host clock at all (the node rebooted
and its timer restarted) it carries on from the host's elapsed time and says so. A
timer that advanced less than the host clock is either a backlog read late (a stalled
reader) or a reboot whose new timer landed just ahead of the old one: the unwrapper
tells them apart by the backlog's signature (see :meth:`TimerUnwrapper._backlog`), and
a discovery packet (:meth:`TimerUnwrapper.expect_reset`) settles it outright. Given the
node's clock estimate, it judges each reading by where that puts it, far more closely
than the host's elapsed time alone can.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

from .errors import CommandError

CLOCK_HZ: Final = 51200
"""The calculation-cycle clock: the data rate is ``CLOCK_HZ / divider``."""
MIN_DIVIDER: Final = 170
MAX_DIVIDER: Final = 51200
DEFAULT_DIVIDER: Final = 512
"""A node's divider as shipped: 100 Hz."""
TICKS_PER_SECOND: Final = 19_660_800
TICKS_PER_CLOCK: Final = TICKS_PER_SECOND // CLOCK_HZ
"""Timer ticks in one period of the 51,200 Hz clock (384): a stream's records are
``divider * TICKS_PER_CLOCK`` ticks apart."""
BITS_PER_BYTE: Final = 10
"""A byte on the serial line at 8N1: a start bit, eight data bits and a stop bit."""
TIMER_MODULUS: Final = 1 << 32
WRAP_SECONDS: Final = TIMER_MODULUS / TICKS_PER_SECOND  # 218.45 s
_HALF_WRAP_SECONDS: Final = WRAP_SECONDS / 2
LINE_REACH: Final = 0.5
"""Seconds a reading may be from the clock estimate's line (the least delay seen:
:mod:`aspp.clock`) and be on time, plus 0.1% of the host time since the last reading
(the line's drift, extrapolated). Above it: a packet that waited in the base station's
queue (a full 4 KiB buffer is 0.36 s at 115200 baud) or a stall of it; below it: the
same, when every packet since the line began had waited so (a saturated line) and the
line is that much above the floor. Further, a reading is late (only a backlog's
signature keeps it from being a restarted timer) or early (a restarted timer)."""
BACKLOG_PAUSE: Final = 0.1
"""Seconds a backlog's reading may arrive later than its timer step says (a pause of the
reader) before its pace is measured again; and the host time it may take beyond half
the device time read (see :meth:`TimerUnwrapper._backlog`). Above the radio's jitter
(20 ms at the most in gx2-sim), far below a reader's stall."""


def ticks_to_seconds(ticks: int) -> float:
    return ticks / TICKS_PER_SECOND


def seconds_to_ticks(seconds: float) -> int:
    """Ticks for ``seconds``, wrapped into the u32 a node would report."""
    return round(seconds * TICKS_PER_SECOND) % TIMER_MODULUS


def byte_time(baudrate: int) -> float:
    """Seconds one byte takes on the serial line."""
    return BITS_PER_BYTE / baudrate


def valid_divider(divider: int) -> bool:
    return MIN_DIVIDER <= divider <= MAX_DIVIDER


def data_rate(divider: int) -> float:
    """Records per second in continuous mode for a calculation-cycle divider."""
    return CLOCK_HZ / divider


def sample_period(divider: int) -> float:
    """Seconds between records in continuous mode (x / 51200)."""
    return divider / CLOCK_HZ


def divider_for_rate(hz: float) -> int:
    """The divider that gives ``hz`` (51200 / x); CommandError unless 170..51200."""
    if isinstance(hz, bool) or not isinstance(hz, (int, float)) or not hz > 0:
        raise CommandError(f"rate must be a positive number of Hz, not {hz!r}")
    divider = round(CLOCK_HZ / hz)
    if not valid_divider(divider):
        raise CommandError(f"rate {hz} Hz needs divider {divider}, out of range "
                           f"{MIN_DIVIDER}..{MAX_DIVIDER} (about 1..301 Hz)")
    return divider


class TimerUnwrapper:
    """Turns one node's timer readings into monotonic seconds since its first reading's
    power-up (the first reading ``t`` gives ``t / 19.6608 MHz``).

    ``tolerance`` is how far (seconds) the timer may disagree with the host clock before
    a reading counts as a reset rather than wraps; it absorbs radio and USB latency (set
    at construction, as are the others).
    ``late_step`` is the longest timer step (seconds) with which a backlog read late can
    begin: the node's sample period times a few (None: any step, for a caller that does
    not know the node's rate). ``expect``, given the host time of a reading, says what
    device time it would have if it had come with the least delay seen (the clock
    estimate's line, on the clock ``host_time`` is on), or None while there is no line:
    with it, a reading is judged against where the node's clock says it belongs, within
    LINE_REACH rather than the tolerance of the last reading's arrival.
    """

    __slots__ = ("_expect", "_fast", "_lag", "_last_host", "_last_ticks", "_passed",
                 "_read", "_reset_by", "_steady", "_total_ticks", "last_was_reset",
                 "late_step", "resets", "tolerance")

    def __init__(self, tolerance: float = 2.0, late_step: float | None = None,
                 expect: Callable[[float], float | None] | None = None) -> None:
        self._total_ticks: int | None = None
        self._last_ticks = 0
        self._last_host: float | None = None
        self.tolerance = tolerance
        self.late_step = late_step
        self._expect = expect
        self._fast = tolerance if expect is None else min(tolerance, LINE_REACH)
        """How far the timer may disagree with the host clock for the fast path of
        :meth:`update` (with a line to judge by: the line's reach)."""
        self.resets = 0
        self.last_was_reset = False
        self._lag = 0.0
        """Seconds the timer is behind the host clock: a backlog not read yet."""
        self._read = 0.0
        self._passed = 0.0
        """Device and host seconds since the backlog's reading was last interrupted."""
        self._reset_by: float | None = None
        """A discovery packet announced a power-up: the host time until which a reading
        on time may still be of the old one (see :meth:`expect_reset`)."""
        self._steady = True
        """No backlog, no reset announced: what the fast path of :meth:`update` needs."""

    def update(self, ticks: int, host_time: float | None = None) -> float:
        """Add one reading (``host_time``: when it arrived, any clock in seconds);
        return the device time in seconds."""
        if not 0 <= ticks < TIMER_MODULUS:
            raise ValueError(f"timer reading {ticks} is not a u32")
        self.last_was_reset = False
        if self._total_ticks is None:
            self._total_ticks = ticks
        else:
            delta = (ticks - self._last_ticks) % TIMER_MODULUS
            if host_time is not None and self._last_host is not None:
                elapsed = host_time - self._last_host
                # the usual reading (one sample period on): no wrap can hide in less
                # than half a wrap of host time, and a timer this close to the host
                # clock is what _reconcile accepts as it is (a host clock that stepped
                # back, a backlog and an announced reset are left to _reconcile)
                if not (self._steady and 0.0 <= elapsed < _HALF_WRAP_SECONDS
                        and -self._fast <= delta / TICKS_PER_SECOND - elapsed
                        <= self._fast):
                    delta = self._reconcile(delta, elapsed, host_time)
            elif self._reset_by is not None:  # announced, and no clock to say more
                delta = self._reset(0.0)
            self._total_ticks += delta
        self._last_ticks = ticks
        if host_time is not None:
            self._last_host = host_time
        return self._total_ticks / TICKS_PER_SECOND

    def expect_reset(self) -> bool:
        """A discovery packet: the node announced a power-up, so its timer restarts.
        The first reading that is not on time, or that arrives more than the tolerance
        after the last one before the packet (records of the old power-up in flight
        arrive within milliseconds), starts the new power-up's count, whatever its
        timer. Returns whether a reset is now due (before any reading there is nothing
        to reset: the first one starts the count)."""
        if self._total_ticks is None:
            return False
        self._reset_by = -math.inf if self._last_host is None \
            else self._last_host + self.tolerance
        self._steady = False
        return True

    # A reading whose timer advanced less than the host clock (by more than the
    # tolerance, or LINE_REACH off the clock estimate's line) is either a backlog read
    # late or a reboot: a reader that stalled reads, when it resumes, records that waited
    # in the kernel; a node that rebooted while the host heard nothing of it (its
    # discovery packet lost) starts a timer that lands anywhere modulo the wrap, and
    # ahead of the old one by less than the host's elapsed time with probability
    # (outage + tolerance) / 218.45 s (issue 19: 6.3% of 10 s power-offs). The line
    # tells a reading late (or early) from one on time far more closely than the last
    # reading's arrival does (LINE_REACH against the tolerance: a reboot whose timer
    # lands within 2 s of where the old one would be is seen), but not a backlog from a
    # reboot: either reading lies above it by the host's elapsed time less the timer
    # step. What does is the backlog's signature:
    # - it begins with the record after the last one read (the stream went on while
    #   nobody read it), so its first step is one sample period, a few if the radio lost
    #   some: at most ``late_step``; a reboot's step is spread over the whole wrap;
    # - it is read at the reader's pace, not the node's: the records come in a burst,
    #   the host's elapsed time far below the device time they span, until the timer has
    #   caught up with the host clock. A rebooted stream taken for one (its new timer a
    #   few periods ahead of the old one: 10 periods in 218.45 s, 0.05% at 100 Hz)
    #   arrives at the node's own pace instead, and is found a fraction of a second on.
    # A discovery packet, when it arrives, settles it before either: expect_reset.

    def _reconcile(self, delta: int, elapsed: float, host_time: float) -> int:
        """Add the wraps that put the reading where the node's clock line says it
        belongs (without a line: the host's elapsed time and any backlog still unread).
        A timer that advanced less than that is a backlog read late if it has a
        backlog's signature (see above), and the timer is right. If no count of wraps
        fits otherwise, the timer restarted: advance by the host's elapsed time (and
        the backlog's lag) instead."""
        seconds = delta / TICKS_PER_SECOND
        if self._reset_by is not None:
            if host_time > self._reset_by or abs(seconds - elapsed - self._lag) > self.tolerance:
                return self._reset(elapsed + self._lag)  # (the device time caught up)
            return delta  # of the old power-up, in flight when the new one was announced
        expected, reach = self._expectation(elapsed, host_time)
        wraps = max(0, round((expected - seconds) / WRAP_SECONDS))
        behind = expected - seconds - wraps * WRAP_SECONDS
        if abs(behind) <= reach:
            self._lag, self._steady = 0.0, True
            return delta + wraps * TIMER_MODULUS
        if behind > 0 and wraps == 0 and self._backlog(seconds, elapsed):
            self._lag, self._steady = behind, False
            return delta
        return self._reset(elapsed + self._lag)  # (the device time caught up)

    def _expectation(self, elapsed: float, host_time: float) -> tuple[float, float]:
        """How far (seconds) the device time should advance for a reading on time, and
        by how much it may miss that either way."""
        if self._expect is not None:
            device = self._expect(host_time)
            if device is not None:
                assert self._total_ticks is not None
                return (device - self._total_ticks / TICKS_PER_SECOND,
                        LINE_REACH + 1e-3 * abs(elapsed))
        return elapsed + self._lag, self.tolerance + 0.01 * elapsed

    def _backlog(self, step: float, elapsed: float) -> bool:
        """Whether a reading ``step`` seconds on, ``elapsed`` host seconds after the
        last, and behind the host clock by more than the tolerance, is a backlog read
        late: one that begins with a step of at most ``late_step`` (or goes on after a
        pause of the reader with one at most the lag further: what its buffer dropped
        when full, the newest, from among what was owed), and is read at least twice as
        fast as it was sampled (within BACKLOG_PAUSE)."""
        late_step = math.inf if self.late_step is None else self.late_step
        # (a step beyond late_step is such a drop, not host time the reader was reading)
        if not self._lag or elapsed - min(step, late_step) > BACKLOG_PAUSE:
            self._read = self._passed = 0.0
            return step <= late_step + self._lag
        self._read += step
        self._passed += elapsed
        return self._passed <= self._read / 2 + BACKLOG_PAUSE

    def _reset(self, advance: float) -> int:
        """The timer restarted: count it, and advance by ``advance`` seconds."""
        self.resets += 1
        self.last_was_reset = True
        self._lag, self._reset_by, self._steady = 0.0, None, True
        return max(0, round(advance * TICKS_PER_SECOND))
