"""Whether the serial line is over capacity, judged from its own evidence: the base
station's queue.

A base station sends the host at most what its baud rate carries (115200 baud: 11,520
bytes a second). Its nodes may offer it more: three nodes at 100 Hz, one of them with
the orientation matrix, make 135% of it. The base station then queues what it cannot
send, until its buffer is full and it drops the rest; every packet read waits behind
that queue, so its arrival says how long the queue is, not when it was sampled, and
the nodes' clocks must learn nothing from it (:meth:`aspp.clock.NodeClock.hold`).

The evidence is the queue itself, in the one quantity the host measures for every
packet: its lag, arrival less device time (``y`` of :mod:`aspp.clock`). A node's lag
changes only by its crystal's drift (0.2 ms a second at the very most) and by waiting.
Each node's least lag over a bin (one SAMPLE_PERIOD of reads) is taken from the
per-record path (:meth:`.nodes.Node.take_lag`), and against that node's floor (its
least lag over the last FLOOR_BINS judged free) it is the least wait of the bin. A
queue in the base station is shared by every node behind it, so:

- **Over capacity**: every node with a floor waits more than QUEUE_MIN in CONFIRM bins
  running, and in none of them is the wait falling (by more than NOISE): the queue is
  growing or standing full. QUEUE_MIN is above what an ordinary busy line makes a node
  wait (behind three other nodes' packets of the longest record, 20 ms) and above a
  radio's retries.
- **Not over capacity, whatever the bytes a second**: a host stall. The host read
  nothing while stalled; what it reads after comes faster than the baud rate, its own
  backlog, and the waits fall bin after bin as it catches up (and so do those of a
  base station's queue that backed up behind the stall, at the line's spare share a
  second). One bin of waiting followed by falling waits is a stall, never a queue. A
  bin in which no node's record was read says nothing.
- **Room again**: while held, every node whose floor was known when the hold began
  waits less than QUEUE_MIN again (the queue drained), above its floor as its crystal
  may have moved it meanwhile (MAX_DRIFT a second held: a floor frozen at the hold's
  start would, after an hour's overload, stand 0.7 s below a node 200 ppm off, and
  the line would never have room again). A node that rebooted meanwhile
  has no floor of its power-up: it says room when its lag fell by QUEUE_MIN from its
  first bin (its first packets came behind the queue); it speaks only when no node
  with a floor read anything. Bytes read with no node's record among them (every
  stream stopped) leave nothing to queue.

Bytes a second were the evidence before (over capacity from 95% of the line over
5 s, room below 90%), and wrong both ways: a 2 s host stall read back at 130% latched
it, and 90% being what an ordinary three-node line carries it never released; a base
station or USB adapter that leaves gaps between packets kept a real 135% overload at
90% of the line and it was never said. Bytes a second are still shown (:attr:`share`).

A replay judges its line on the recording's own clock (:meth:`LineLoad.replayed`): the
reads' recorded times, not the wall clock it plays them by, so that at any speed its
nodes' clocks are held where the live gateway's were, and ``time`` is the recorded one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from aspp.clock import MAX_DRIFT

SPAN = 5.0
"""Seconds over which the line's bytes per second are shown."""
QUEUE_MIN = 0.030
"""Seconds every node must wait above its floor for the base station to hold a queue."""
NOISE = 0.005
"""Seconds a bin's wait may fall and still count as a queue standing (full, its length
moving by a packet or two): a queue that drains slower than this a second is one the
line's spare share (0.5%) barely empties."""
CONFIRM = 3
"""Bins running with the queue's evidence before the line is said over capacity."""
FLOOR_BINS = 20
"""Bins judged free whose least lag is a node's floor (at the largest drift a crystal
has, 200 ppm, the floor moves 4 ms over them: well inside QUEUE_MIN)."""
FLOOR_MIN_BINS = 3
"""Bins a node needs judged free before its floor counts."""

Lags = Iterable[tuple[int, float, int]]
"""Each node's (address, least lag of the bin or inf, power-up count)."""


@dataclass
class _Track:
    """What the judge keeps of one node's power-up."""

    power_up: int
    free: deque[float] = field(default_factory=lambda: deque(maxlen=FLOOR_BINS))
    """Least lags of recent bins judged free."""
    floor: float | None = None
    """While held: its floor when the hold began (None: it had none)."""
    first_held: float | None = None
    """While held, a node with no floor: its least lag in its first bin."""
    last: float = math.inf
    """Its least lag in the last bin it was read in."""

    def known_floor(self) -> float | None:
        return min(self.free) if len(self.free) >= FLOOR_MIN_BINS else None


class LineLoad:
    """One serial line: what it carried over the last SPAN, and whether the base station
    behind it holds a queue (:attr:`over`), judged once a bin from its nodes' lags."""

    def __init__(self, capacity: float, lags: Callable[[], Lags] = tuple) -> None:
        self.capacity = capacity
        """Bytes a second the line carries at most (the baud rate over 10 bits)."""
        self._lags = lags
        """Takes each node's least lag since the last call (:data:`Lags`)."""
        self._samples: deque[tuple[float, int]] = deque()
        self._tracks: dict[int, _Track] = {}
        self._queued = 0
        """Bins running with the queue's evidence."""
        self.over = False
        """Whether the line is over capacity now."""
        self.wait = 0.0
        """Seconds the nodes waited above their floors in the last bin judged (the
        least of them: the queue's length)."""
        self.share = 0.0
        """What the line carried over SPAN at the last sample, as a share of its
        capacity (shown; it judges nothing)."""
        self._bytes_at_bin = 0
        self._held_at = 0.0
        """When (the bins' clock) the line was last said over capacity."""
        self._next: float | None = None
        """A replay's next sample, on the recording's clock (:meth:`replayed`)."""

    # -- once a bin ----------------------------------------------------------------------

    def sample(self, now: float, bytes_read: int) -> bool:
        """End a bin (``now`` on the monotonic clock, ``bytes_read`` the link's count so
        far): judge it from the nodes' lags; return True when :attr:`over` changed."""
        samples = self._samples
        samples.append((now, bytes_read))
        while len(samples) > 1 and samples[1][0] <= now - SPAN:
            samples.popleft()
        self.share = self.bytes_per_s(now, bytes_read) / self.capacity
        read = bytes_read > self._bytes_at_bin
        self._bytes_at_bin = bytes_read
        lags = {address: (lag, power_up) for address, lag, power_up in self._lags()}
        was = self.over
        self._judge(lags, read, now)
        return self.over != was

    def link_down(self) -> None:
        """The base station is gone: its queue with it (a replugged one starts empty)."""
        self.over = False
        self._queued = 0
        for track in self._tracks.values():
            track.floor = track.first_held = None
            track.last = math.inf

    def _judge(self, lags: dict[int, tuple[float, int]], read: bool, now: float) -> None:
        """The rule of the module's docstring, on one bin's lags."""
        tracks = self._tracks
        seen: dict[int, _Track] = {}
        for address, (lag, power_up) in lags.items():
            track = tracks.get(address)
            if track is None or track.power_up != power_up:
                track = tracks[address] = _Track(power_up)  # (a new power-up: no floor)
            if lag < math.inf:
                seen[address] = track
        if not seen:  # nothing of the nodes' read: a stall says nothing, a silence room
            if self.over and read:
                self._release()
            return
        if self.over:
            self._while_held(lags, seen, MAX_DRIFT * (now - self._held_at))
        else:
            self._while_free(lags, seen)
            if self.over:
                self._held_at = now
        for address, track in seen.items():
            track.last = lags[address][0]

    def _while_free(self, lags: dict[int, tuple[float, int]],
                    seen: dict[int, _Track]) -> None:
        waits, standing = [], True
        for address, track in seen.items():
            floor = track.known_floor()
            if floor is None:
                continue
            lag = lags[address][0]
            waits.append(lag - floor)
            standing = standing and lag >= track.last - NOISE
        queued = bool(waits) and min(waits) > QUEUE_MIN and standing
        self._queued = self._queued + 1 if queued else 0
        if waits:
            self.wait = max(min(waits), 0.0)
        if self._queued >= CONFIRM:
            self.over = True
            for address, track in seen.items():
                track.floor = track.known_floor()
                track.first_held = None if track.floor is not None else lags[address][0]
            return
        for address, track in seen.items():
            floor = track.known_floor()
            lag = lags[address][0]
            if floor is None or lag - floor <= QUEUE_MIN:  # (a waiting bin is no floor)
                track.free.append(lag)

    def _while_held(self, lags: dict[int, tuple[float, int]], seen: dict[int, _Track],
                    drifted: float) -> None:
        """``drifted``: how far a node's floor may have moved since the hold began."""
        with_floor = {a: t for a, t in seen.items() if t.floor is not None}
        if with_floor:
            waits = [lags[a][0] - t.floor for a, t in with_floor.items()]  # type: ignore[operator]
            self.wait = max(min(waits), 0.0)
            if max(waits) < QUEUE_MIN + drifted:
                self._release()
            return
        drained = True
        for address, track in seen.items():
            lag = lags[address][0]
            if track.first_held is None:
                track.first_held = lag
            drained = drained and lag < track.first_held - QUEUE_MIN
        if drained:
            self._release()

    def _release(self) -> None:
        self.over = False
        self._queued = 0
        for track in self._tracks.values():
            if track.floor is not None:  # (still its floor: the queue is gone from above it)
                track.free.clear()
                track.free.extend([track.floor] * FLOOR_MIN_BINS)
            track.floor = track.first_held = None

    # -- a replay ------------------------------------------------------------------------

    def replayed(self, now: float, bytes_read: int, period: float) -> bool:
        """A replay's read, recorded at ``now`` (the recording's monotonic clock), after
        ``bytes_read`` bytes: the bins the live gateway closed every ``period`` up to
        it, closed now on the recording's clock (each with the bytes read before it).
        True when :attr:`over` changed."""
        following = self._next
        if following is not None and now < following:
            if now >= following - period:
                return False  # (the per-read path of a replay: nothing due)
            # the recording's clock went back: another run of the gateway, whose line
            # is judged afresh, as that gateway's was
            self._samples.clear()
            self._tracks.clear()
            changed = self.over
            self.link_down()
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
        return (f"line over capacity: the base station queues {1e3 * self.wait:.0f} ms of "
                f"packets ({100 * self.share:.0f}% of {self.capacity:.0f} B/s read): "
                "sample times unreliable")
