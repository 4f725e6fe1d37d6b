"""Whether the serial line is over capacity, judged from its own evidence: the base
station's queue.

A base station sends the host at most what its baud rate carries (115200 baud: 11,520
bytes a second). Its nodes may offer it more: three nodes at 100 Hz, one of them with
the orientation matrix, make 135% of it. The base station then queues what it cannot
send, until its buffer is full and it drops the rest; every packet read waits behind
that queue, so its arrival says how long the queue is, not when it was sampled, and
the nodes' clocks must learn nothing from it (:meth:`aspp.clock.NodeClock.hold`).

The evidence is the queue itself, in what the host measures for every packet: how long
after its clock's line it arrived (its wait above the line, :meth:`.nodes.Node.tally`).
A line follows the node's floor and drift, not a queue (the packets above it move it
by no more than the drift's rate bound), and a line held stays where it was, so a
wait above it is the packet's wait. Each node's least wait over a bin (a SAMPLE_PERIOD
of reads) comes from the per-record path (:meth:`.nodes.Node.take_wait`); against its
floor (its least over the last FLOOR_BINS judged free) it is how long the fastest of
its packets waited. A queue in the base station is shared by every node behind it:

- **Over capacity**: every node with a floor waits more than QUEUE_MIN in CONFIRM bins
  running, and in none of them is the wait falling (by more than NOISE): the queue is
  growing or standing full. QUEUE_MIN is above what an ordinary busy line makes a node
  wait (behind three other nodes' packets of the longest record, 20 ms) and above a
  radio's retries; CONFIRM is above two seconds of gx2-sim's 50 ms output stalls
  bunched at 90% (a queue of 300 ms that drains: ``gx2sim`` seed 9 of the sweep).
  While the evidence runs short of CONFIRM the line is :attr:`~LineLoad.suspect`, and
  its nodes' clocks take no points (:meth:`aspp.clock.NodeClock.pause`): a line young
  enough to follow the queue would otherwise do so before the hold.
- **Not over capacity, whatever the bytes a second**: a host stall. The host read
  nothing while stalled; what it reads after comes faster than the baud rate, its own
  backlog, and the waits fall bin after bin as it catches up (and so do those of a
  base station's queue that backed up behind the stall, at the line's spare share a
  second). One bin of waiting followed by falling waits is a stall, never a queue. A
  bin in which no node's record was read says nothing.
- **Room again**: while held, every node whose floor was known when the hold began
  waits less than QUEUE_MIN above it again (the queue drained), plus as far as its held
  line may have gone meanwhile (:meth:`aspp.clock.NodeClock.held_error`: the drift's
  uncertainty over the seconds held, so an hour's overload still ends). A node with no
  floor of this line (rebooted, or new, during the hold) says room when its wait fell
  by QUEUE_MIN from its first bin; it speaks only when no node with a floor read
  anything. Bytes read with no node's record among them (every stream stopped) leave
  nothing to queue, and the base station gone takes its queue with it.

A floor is only taken from a node whose clock has seen its floor (a packet that did
not wait: :attr:`aspp.clock.NodeClock.floor_seen`): a gateway started on a line
already over capacity reads its nodes' packets back to back behind a full queue, and
took that queue for their floors. Such nodes say that their floor was never seen, and
that ``time`` may be late by that wait (:mod:`gateway.daemon.health`); and while no
node has shown its floor, a line read at AT_CAPACITY of its baud rate over SPAN is
taken to be over capacity (room again once the waits fall by QUEUE_MIN). A base
station that leaves gaps between packets, started behind a full queue, shows neither:
its nodes' packets may then show a floor that is the queue's.

Bytes a second were the evidence before (over capacity from 95% of the line over
5 s, room below 90%), and wrong both ways: a 2 s host stall read back at 130% latched
it, and 90% being what an ordinary three-node line carries it never released; a base
station or USB adapter that leaves gaps between packets kept a real 135% overload at
90% of the line and it was never said. Bytes a second are still shown (:attr:`share`).

Bins are closed on the reads' own clock (:meth:`LineLoad.read`), live and replayed
alike: a replay, at any speed, holds its nodes' clocks exactly where the live gateway
held them, and its ``time`` is the recorded one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from aspp.clock import NodeClock

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
"""Bins judged free whose least wait is a node's floor."""
FLOOR_MIN_BINS = 3
"""Bins a node needs judged free before its floor counts."""
AT_CAPACITY = 0.95
"""Share of the line's baud rate read over SPAN from which a line none of whose nodes
has shown its floor is taken to be behind a full queue."""


class Waited(NamedTuple):
    """What one node's records of a bin say of its line's queue."""

    address: int
    wait: float
    """The least wait above its clock's line (seconds; inf: no timed record)."""
    epoch: object
    """Its line's: waits of two epochs (a reboot, the node made anew, the floor its clock
    had seen taken back at the lock) never compare."""
    floor_seen: bool
    """Whether its clock has seen its floor on this line."""
    held_error: float
    """How far its held line may have gone since the hold (seconds; 0 unless held)."""


@dataclass
class _Track:
    """What the judge keeps of one node's line."""

    epoch: object
    free: deque[float] = field(default_factory=lambda: deque(maxlen=FLOOR_BINS))
    """Least waits of recent bins judged free."""
    floor: float | None = None
    """While held: its floor when the hold began (None: it had none)."""
    first_held: float | None = None
    """While held, a node with no floor: its least wait in its first bin."""
    last: float = math.inf
    """Its least wait in the last bin it was read in."""

    def known_floor(self) -> float | None:
        return min(self.free) if len(self.free) >= FLOOR_MIN_BINS else None


class LineLoad:
    """One serial line: what it carried over the last SPAN, and whether the base station
    behind it holds a queue (:attr:`over`), judged once a bin from its nodes' waits."""

    def __init__(self, capacity: float,
                 waits: Callable[[], Iterable[Waited]] = tuple) -> None:
        self.capacity = capacity
        """Bytes a second the line carries at most (the baud rate over 10 bits)."""
        self._waits = waits
        """Takes each node's evidence since the last call."""
        self._samples: deque[tuple[float, int]] = deque()
        self._tracks: dict[int, _Track] = {}
        self._queued = 0
        """Bins running with the queue's evidence."""
        self._evidence_at = -math.inf
        """When a bin last held a node's record (a slow node's bins between its records
        say nothing; SPAN without any, the streams stopped)."""
        self._after_gap = False
        """Whether a bin with nothing read came since the last with records."""
        self.over = False
        """Whether the line is over capacity now."""
        self.wait = 0.0
        """Seconds the nodes waited above their floors in the last bin judged (the
        least of them: the queue's length)."""
        self.share = 0.0
        """What the line carried over SPAN at the last bin, as a share of its capacity
        (shown; it judges nothing)."""
        self._bytes_at_bin = 0
        self._next: float | None = None
        """When the next bin closes, on the reads' clock (:meth:`read`)."""

    # -- the bins, closed on the reads' clock --------------------------------------------

    def read(self, now: float, bytes_read: int, period: float) -> bool:
        """A read made at ``now`` (monotonic seconds: the live clock, or a replay's
        recorded one), after ``bytes_read`` bytes: the bins due every ``period`` up to
        it closed first, each with the bytes read before it. True when :attr:`over` or
        :attr:`suspect` changed."""
        following = self._next
        if following is not None and now < following:
            if now >= following - period:
                return False  # (the per-read path: nothing due)
            # the clock went back: a replay's next run of the gateway, whose line is
            # judged afresh, as that gateway's was
            self._samples.clear()
            self._tracks.clear()
            changed = self.over or self.suspect
            self.link_down()
            self._next = now + period
            return changed
        if following is None:
            following = now
        elif now - following > SPAN:  # a silence: only its last SPAN is measured
            following += math.floor((now - SPAN - following) / period) * period
        was = self.over, self.suspect
        while following <= now:
            self.sample(following, bytes_read)
            following += period
        self._next = following
        return (self.over, self.suspect) != was

    def sample(self, now: float, bytes_read: int) -> bool:
        """Close a bin at ``now`` (``bytes_read`` the link's count so far): judge it
        from the nodes' waits; return True when :attr:`over` changed."""
        samples = self._samples
        samples.append((now, bytes_read))
        while len(samples) > 1 and samples[1][0] <= now - SPAN:
            samples.popleft()
        self.share = self.bytes_per_s(now, bytes_read) / self.capacity
        read = bytes_read > self._bytes_at_bin
        self._bytes_at_bin = bytes_read
        was = self.over
        self._judge(list(self._waits()), read, now)
        return self.over != was

    @property
    def suspect(self) -> bool:
        """Whether the last bins show the queue's evidence, not yet for CONFIRM bins:
        the nodes' clocks learn nothing meanwhile (:meth:`aspp.clock.NodeClock.pause`),
        and either the evidence is confirmed (over capacity, held from the line as it
        stood) or it goes (a host stall's backlog read back) and they learn again."""
        return self._queued > 0 and not self.over

    def tell(self, clock: NodeClock) -> None:
        """Make a node's clock as the line is: paused while :attr:`suspect`, held while
        :attr:`over`, released once it is not (a clock already so is left)."""
        clock.pause(self.suspect)
        if self.over and not clock.held:
            clock.hold()
        elif not self.over and clock.held:
            clock.release()

    def _spanned(self) -> bool:
        """Whether the bytes a second span enough of SPAN to judge by."""
        samples = self._samples
        return samples[-1][0] - samples[0][0] >= 0.8 * SPAN

    def link_down(self) -> None:
        """The base station is gone: its queue with it (a replugged one starts empty)."""
        self.over = False
        self._queued = 0
        for track in self._tracks.values():
            track.floor = track.first_held = None
            track.last = math.inf

    # -- the rule ------------------------------------------------------------------------

    def _judge(self, evidence: list[Waited], read: bool, now: float) -> None:
        """The rule of the module's docstring, on one bin's waits."""
        tracks = self._tracks
        for gone in tracks.keys() - {w.address for w in evidence}:
            del tracks[gone]  # (a node a reload removed)
        seen: list[tuple[Waited, _Track]] = []
        for waited in evidence:
            track = tracks.get(waited.address)
            if track is None or track.epoch != waited.epoch:
                track = tracks[waited.address] = _Track(waited.epoch)  # (no floor yet)
            if waited.wait < math.inf:
                seen.append((waited, track))
        if not seen:
            # Nothing of the nodes' read. Bytes but no record: a slow node's bin between
            # its records, or a full base station's drop of them, says nothing; SPAN of
            # such bins, the streams stopped, and a queue with them (a held line
            # released at the first such bin, with a 1 Hz node, a neighbour's stream
            # filling the line: an outside review). Nothing read at all: a stall of
            # the host's, or a gap in its reads (a port by URL), says nothing either
            # (a count reset there never confirmed a queue read in gaps of 1 s), but
            # the bin after it cannot be a queue's third (a stall's backlog, read in
            # it, stands as high as the stall was long: it falls in the bin after).
            self._after_gap = self._after_gap or not read
            if read and now - self._evidence_at > SPAN:
                if self.over:
                    self._release()
                self._queued = 0
            return
        self._evidence_at = now
        if self.over:
            self._while_held(seen)
        else:
            self._while_free(seen)
        self._after_gap = False
        for waited, track in seen:
            track.last = waited.wait

    def _while_free(self, seen: list[tuple[Waited, _Track]]) -> None:
        waits, standing = [], True
        for waited, track in seen:
            floor = track.known_floor()
            if floor is None:
                continue
            waits.append(waited.wait - floor)
            standing = standing and waited.wait >= track.last - NOISE
        queued = bool(waits) and min(waits) > QUEUE_MIN and standing
        if not waits and not any(w.floor_seen for w, _ in seen):
            # no node has ever shown its floor, and the line reads at its baud rate: a
            # gateway started behind a queue already full (no wait shows it)
            queued = self._spanned() and self.share >= AT_CAPACITY
            self.wait = math.nan  # (no floor to measure the queue from)
        self._queued = self._queued + 1 if queued else 0
        if self._after_gap:
            self._queued = min(self._queued, CONFIRM - 1)
        if waits:
            self.wait = max(min(waits), 0.0)
        if self._queued >= CONFIRM:
            self.over = True  # (the reason's wait: the least of the nodes' with floors)
            for waited, track in seen:
                track.floor = track.known_floor()
                track.first_held = None if track.floor is not None else waited.wait
            return
        for waited, track in seen:
            floor = track.known_floor()
            if waited.floor_seen and (floor is None or waited.wait - floor <= QUEUE_MIN):
                track.free.append(waited.wait)  # (a waiting bin is no floor)

    def _while_held(self, seen: list[tuple[Waited, _Track]]) -> None:
        with_floor = [(w, t) for w, t in seen if t.floor is not None]
        if with_floor:
            waits = [w.wait - t.floor for w, t in with_floor]  # type: ignore[operator]
            self.wait = max(min(waits), 0.0)
            if all(w.wait - t.floor < QUEUE_MIN + w.held_error  # type: ignore[operator]
                   for w, t in with_floor):
                self._release()
            return
        drained = True
        for waited, track in seen:
            if track.first_held is None:
                track.first_held = waited.wait
            drained = drained and waited.wait < track.first_held - QUEUE_MIN
        if drained:
            self._release()

    def _release(self) -> None:
        self.over = False
        self._queued = 0
        for track in self._tracks.values():
            # (the line starts over from fresh packets: its floor is learnt again)
            track.free.clear()
            track.floor = track.first_held = None

    # -- what it shows -------------------------------------------------------------------

    def bytes_per_s(self, now: float, bytes_read: int) -> float:
        """Bytes read per second over the last SPAN."""
        if not self._samples:
            return 0.0
        at, before = self._samples[0]
        return (bytes_read - before) / (now - at) if now > at else 0.0

    def reason(self) -> str:
        """The gateway's reason while the line is over capacity."""
        queue = ("no node shows its floor" if math.isnan(self.wait)
                 else f"the base station queues {1e3 * self.wait:.0f} ms of packets")
        return (f"line over capacity: {queue} ({100 * self.share:.0f}% of "
                f"{self.capacity:.0f} B/s read): sample times unreliable")
