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
timer that advanced less than the host clock is data read late (a stalled reader), not
a reboot; so a reboot is seen here only when the new timer is behind the old one (the
node had been up longer than it has been back), and the gateway has other signs.
"""

from __future__ import annotations

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
    a reading counts as a reset rather than wraps; it absorbs radio and USB latency.
    """

    __slots__ = ("_last_host", "_last_ticks", "_total_ticks", "last_was_reset", "resets",
                 "tolerance")

    def __init__(self, tolerance: float = 2.0) -> None:
        self._total_ticks: int | None = None
        self._last_ticks = 0
        self._last_host: float | None = None
        self.tolerance = tolerance
        self.resets = 0
        self.last_was_reset = False

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
                # than half a wrap of host time, and a timer no further ahead of the
                # host clock than the tolerance is what _reconcile accepts as it is (a
                # host clock that stepped back is left to _reconcile)
                if not (0.0 <= elapsed < _HALF_WRAP_SECONDS
                        and delta <= (elapsed + self.tolerance) * TICKS_PER_SECOND):
                    delta = self._reconcile(delta, elapsed)
            self._total_ticks += delta
        self._last_ticks = ticks
        if host_time is not None:
            self._last_host = host_time
        return self._total_ticks / TICKS_PER_SECOND

    def _reconcile(self, delta: int, host_elapsed: float) -> int:
        """Add the wraps ``host_elapsed`` needs. A timer that advanced less than the
        host clock (with no wrap missed) was read late: a reader stalled and read a
        backlog, and the timer is right. If no count of wraps fits otherwise, the timer
        restarted: advance by the host's elapsed time instead."""
        seconds = delta / TICKS_PER_SECOND
        wraps = max(0, round((host_elapsed - seconds) / WRAP_SECONDS))
        seconds += wraps * WRAP_SECONDS
        slack = self.tolerance + 0.01 * host_elapsed
        if abs(seconds - host_elapsed) <= slack or (wraps == 0 and seconds < host_elapsed):
            return delta + wraps * TIMER_MODULUS
        self.resets += 1
        self.last_was_reset = True
        return max(0, round(host_elapsed * TICKS_PER_SECOND))
