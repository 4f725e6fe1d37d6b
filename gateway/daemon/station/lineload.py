"""How full the serial line is, and whether it is over capacity.

A base station sends the host at most what its baud rate carries (115200 baud: 11,520
bytes a second). Its nodes may send it more: three nodes at 100 Hz, one of them with
the orientation matrix, make 135% of it. The base station then queues what it cannot
send until its buffer is full and drops the rest; every packet read waits behind that
queue, so its arrival says nothing of when it was sampled. From the host the sign is
the line itself: bytes arriving, second after second, at the rate the line carries
and no slower. That is judged here from the bytes read, sampled once a second
(nothing on the per-record path).

The thresholds have room between them so that a line near its capacity does not flap:
it is over capacity from AT_CAPACITY of the line over SPAN, and has room again below
ROOM. A line at 90% (two or three nodes streaming at a rate a little under what it
carries, as ``bench/timesync.py`` runs it, stalls included) is under both: a stall
holds bytes back, it does not add any, and SPAN averages the catching up.

A replay judges its line on the recording's own clock (:meth:`LineLoad.replayed`): the
reads' recorded times, not the wall clock it plays them by. At ``speed=5`` the wall
clock sees five times the bytes a second, at ``speed=0`` all of them at once, and a
line the recording shows at 90% would be judged over capacity: its nodes' clocks held
where the live gateway's were not, and ``time`` no longer the recorded one.
"""

from __future__ import annotations

import math
from collections import deque

SPAN = 5.0
"""Seconds over which the line's bytes per second are measured."""
AT_CAPACITY = 0.95
"""Share of the line's capacity, over SPAN, from which it is over capacity."""
ROOM = 0.90
"""Share under which a line over capacity has room again."""


class LineLoad:
    """The bytes read from one serial line over the last SPAN, against what it carries."""

    def __init__(self, capacity: float) -> None:
        self.capacity = capacity
        """Bytes a second the line carries at most (the baud rate over 10 bits)."""
        self._samples: deque[tuple[float, int]] = deque()
        self.over = False
        """Whether the line is over capacity now."""
        self.share = 0.0
        """What the line carried over SPAN at the last sample, as a share of its
        capacity."""
        self._next: float | None = None
        """A replay's next sample, on the recording's clock (:meth:`replayed`)."""

    def sample(self, now: float, bytes_read: int) -> bool:
        """Add a sample (``now`` on the monotonic clock, ``bytes_read`` the link's
        count so far); return True when :attr:`over` changed."""
        samples = self._samples
        samples.append((now, bytes_read))
        while len(samples) > 1 and samples[1][0] <= now - SPAN:
            samples.popleft()
        if now - samples[0][0] < SPAN * 0.8:
            return False  # too short a span to judge by (the link just opened)
        self.share = share = self.bytes_per_s(now, bytes_read) / self.capacity
        over = share >= AT_CAPACITY if not self.over else share >= ROOM
        changed, self.over = over != self.over, over
        return changed

    def replayed(self, now: float, bytes_read: int, period: float) -> bool:
        """A replay's read, recorded at ``now`` (the recording's monotonic clock), after
        ``bytes_read`` bytes: the samples the live gateway took every ``period`` up to
        it, taken now on the recording's clock (each with the bytes read before it).
        True when :attr:`over` changed."""
        following = self._next
        if following is not None and now < following:
            if now >= following - period:
                return False  # (the per-read path of a replay: nothing due)
            # the recording's clock went back: another run of the gateway, whose line
            # is judged afresh, as that gateway's was
            self._samples.clear()
            changed, self.over = self.over, False
            self._next = now + period
            return changed
        if following is None:
            following = now
        elif now - following > SPAN:  # a silence: only its last SPAN is measured
            following += math.floor((now - SPAN - following) / period) * period
        was = self.over
        while following <= now:
            self.sample(following, bytes_read)
            following += period
        self._next = following
        return self.over != was

    def bytes_per_s(self, now: float, bytes_read: int) -> float:
        """Bytes read per second over the last SPAN."""
        if not self._samples:
            return 0.0
        at, before = self._samples[0]
        return (bytes_read - before) / (now - at) if now > at else 0.0

    def reason(self) -> str:
        """The gateway's reason while the line is over capacity."""
        return (f"line over capacity: {100 * self.share:.0f}% of {self.capacity:.0f} B/s: "
                "sample times unreliable")
