"""A node's clock as the host sees it: where each record's device time falls on the
host's clock. Pure: fed (device seconds, host seconds) pairs, it keeps no clock.

The model, for each packet: host = offset + (1 + drift) * device + delay. Every node's
crystal runs at its own rate (drift, tens of ppm), and delay, the packet's way from
the node to the host's read, is never negative but heavy-tailed: a packet may wait
behind others in the base station or the USB adapter for milliseconds, or for
hundreds in a stall. An average of host - device carries the mean delay as a bias and
follows every stall; the packets that came through fastest say far more.

So, as the issue and the literature on one-way delay propose (Moon, Skelly and
Towsley, "Estimation and removal of clock skew from network delay measurements",
INFOCOM 1999): in the plane of x = device and y = host - device, every packet lies on
or above the line y = offset + drift * x, and the packets that waited least are the
lower convex hull of the points. Of the lines below every point, the one that is
closest to all of them on average (a linear programme) supports the hull where x is
the middle of the window; its slope is where the drift is drawn to (clamped to
MAX_DRIFT, at a bounded rate: DRIFT_RATE). The window slides (about a minute, so a
drift that changes with temperature is followed); late packets lie above the hull and
move nothing.

Cost: points are kept as the lower hull of each BLOCK of device time (a monotone
chain, amortised O(1) a point), and the window's hull is rebuilt from the blocks'
vertices when a block closes; a point that falls below the line meanwhile (a faster
packet than any before, or a drift that changed) lowers the line to it at once. A
refit touches only a few hundred vertices, once every BLOCK seconds.

A serial line over capacity breaks the model's premise that some packets come through
fast: every packet then waits behind a queue that grows until the base station's buffer
is full, so the lowest points rise with the queue (a drift of hundreds of ppm) and, a
window later, the floor under them leaves and the line jumps by the queue's length
(issue 21: 306-314 ms). The gateway, which sees the line's load, :meth:`~NodeClock.hold`s
the estimate for as long as it lasts; and whatever moves the line, ``time`` follows it
at a bounded rate (SLEW), never by a step. What a hold, a release, a reboot, a packet
and an outage do to the estimate, in each state it can be in, is one table:
:mod:`aspp.clockstate`.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

from .clockstate import (
    FITTED,
    FRESH,
    HELD_FRESH,
    HELD_STATES,
    HOLD,
    OUTAGE,
    POINT,
    RELEASE,
    RESET,
    ClockEvent,
    ClockState,
    after,
)

# The drift the estimate may take. The reference gives the node's clock: "The system
# clock has an accuracy of +/- 0.01%" (3DM-GX2 Data Communications Protocol, the
# timer field), so 100 ppm; the host's clock, against which the drift is measured, may
# be as far off again when nothing disciplines it (a PC's crystal, tens of ppm; NTP
# keeps it within a few). A fit beyond the sum is wrong (too few points, or a backlog
# growing under the packets), not the crystals.
NODE_CLOCK_ACCURACY = 100e-6
HOST_CLOCK_ACCURACY = 100e-6
MAX_DRIFT = NODE_CLOCK_ACCURACY + HOST_CLOCK_ACCURACY
WINDOW = 60.0
"""Seconds of device time the hull spans."""
BLOCK = 2.0
"""Seconds of device time whose points are reduced to their own lower hull."""
LOCK_SPAN = 1.0
"""Seconds of points before the estimate counts as locked (the drift then has a base
line: an error of 50 ppm over the span is 50 us, well inside the spread)."""
LOCK_POINTS = 10
EARLY = 4 * BLOCK
"""Seconds from the first point during which the line is fitted every EARLY_STEP (and
at every point below it): the drift's base line is still short, and the hull small."""
EARLY_STEP = 0.1
# How fast the drift may move. A long run of late packets would otherwise move the
# hull's middle edge: two nodes at one rate drift past each other by their crystals'
# difference, and for as long as one node's packet is ready just before the other's,
# the other's packets all wait behind it on the serial line: tens of seconds of a
# floor that jumps by a packet's time and ramps back down, no packet of that node near
# the true floor meanwhile. A drift fitted over T seconds is uncertain by about
# FLOOR_NOISE / T, so once fitted over SETTLE_SPAN it moves at most
# max(DRIFT_RATE, FLOOR_NOISE / T**2) a second: quickly while the base line is short,
# then no faster than a crystal follows its temperature (about a ppm per kelvin;
# DRIFT_RATE allows 6 ppm a minute). T is kept through a reset: the drift is the
# crystal's, not the power-up's. A drift at the clamp (MAX_DRIFT) is not held: no
# crystal is that far off, so late points drew it there, and the bound would keep it
# for minutes (a stream whose first packets all queued, then one found the line free
# 7 s in: the edge joining them sloped beyond the clamp, and 115 s later the drift was
# still -161 ppm, ``time`` 10 ms early; issue 32, FIFO seed 67). It goes to the edge's
# slope at the next fit, and is bounded from there. What this and the ideas measured
# against it give over the line models' sweep (bench/sweep.py) is in
# docs/performance-history.md, "Sample time over the sweep".
SETTLE_SPAN = 10.0
DRIFT_RATE = 0.1e-6
FLOOR_NOISE = 0.5e-3
RESIDUALS = 256
"""Recent residuals (delay above the line) kept for the spread."""
SLEW = 0.5
"""When the line moves against the last time given, times follow it at this share of
the device's rate at most: a line that drops (a faster packet than any before) is met
with times advancing at half the device's rate (never backwards, never twice the same:
two records of one cycle are one step of a double apart); a line that rises (old low
points leaving the window, a refit) with times advancing at one and a half. So ``time``
never steps against the device's time by more than half the time between two
records."""

# How long since the line last saw its floor, and what that may cost (issue 32). A
# packet shows the floor when it did not wait (:func:`waited`: it began on the serial
# line later than the floor's noise after the packet before it ended) and its delay
# above the line is within the floor's noise (FLOOR_NOISE). A packet that began as
# another ended reached the base station at some instant while that one was on the
# line, which the host cannot see: its arrival bounds its sample from above only, and
# a line resting on such packets (a node whose samples fall just behind another's)
# shows nothing of its floor however close they lie to it. (An earlier rule, a packet
# near the line as it stood at the last sighting too, missed exactly that node, its
# line never having seen a floor to rise from, and aged the floor of a good node for
# ever once an early, wrong drift had carried that reference below every packet:
# FIFO seed 9, node 100, ``time`` within 0.06 ms and its floor 76 s unseen.) The
# margin is FLOOR_NOISE, not a byte's time, because the host's reads add their own
# latency: a packet judged free by a read later than the one before by more than the
# margin lies at least that far above a line resting on its waiting stationmates.
# The age is counted in device seconds, from that packet to the newest: the line is
# extrapolated along the device's time, a replay ages it as live did, and a node that
# sends nothing ages nothing (it is silent, which health says).
#
# What is true while no packet comes near the floor. Write F for the true floor (the
# least delay a packet can have, on the node's true drift D*), L for the line (drift
# D), R for the line as it stood at the last sighting x_f (drift D_f). At device x:
#
#     L(x) - F(x) = [L(x) - R(x)] + [R(x_f) - F(x_f)] + (D_f - D*) (x - x_f)
#
# - L - R is seen: how far the line moved from the floor last seen, its drift's moves
#   included (0 while the line is only extrapolated; the queue's wait once it rises
#   onto the waiting packets).
# - R(x_f) - F(x_f) is the estimate's error where it last saw its floor: what it is on
#   a free line (the premise of the whole estimate: the fastest packets come through
#   with the floor's delay), not part of the bound.
# - (D_f - D*) (x - x_f): the drift is never exact. It is drawn to the slope of the
#   hull's edge across the window's middle (_fit), whose two ends p1 <= middle <= p2
#   are packets, so on or above the floor (L(p) >= F(p)). At the sighting, the newest
#   packet, at the window's end and so half a window or more after p1 once the window
#   is full, lies within FLOOR_NOISE of the floor and of the line: the slope is then
#   off (upwards, the way that makes ``time`` late later) by at most FLOOR_NOISE over
#   half the window. DRIFT_ERROR allows it over a quarter (33 ppm), for the rate bound
#   (SETTLE_SPAN) holding the drift behind the edge's and a window not yet full (a
#   drift at MAX_DRIFT it does not hold: it goes to the edge's at the next fit). That
#   is an allowance, not a proof: a line younger than a window, or a drift the rate
#   bound holds far from the edge's, may be further off (docs/performance-history.md, "Sample
#   time over the sweep", measures what is left).
#
# So ``time`` may be late by up to |L - R| + DRIFT_ERROR * age + FLOOR_NOISE
# (:meth:`NodeClock.late_bound`). The move counts whichever way it went: a line lowered
# since the sighting (to a faster packet that waited all the same) says the line then
# lay that far above a packet, and so the sighting's own error may be as large; counted
# with its sign it cancelled the drift's allowance and a WARN said "late by up to 0.0
# ms". FLOOR_NOISE is the sighting's own margin. Measured against the truth over the
# sweep's line models (bench/linemodels.py, ``bound_broken``): before, 13,063 of the
# 65,079 FIFO samples given a bound (40 seeds of 120 s) were later than it; with this
# bound none of gx2-sim's 58,906 nor the FIFO's (median bound 2.3 and 2.7 ms), and
# tests/aspp/test_clock_sweep.py holds three of those seeds to it. No packet can show
# less: a packet that waited says only that the floor is below it, so packets bound the
# line from the other side only (at each packet's device time, ``time`` is early by at
# most that packet's delay above the line), and a line that never saw its floor (a node
# whose samples fall just behind another's from the start) is late by the wait: its age
# runs from its first packet, but no bound on the wait comes with it (two runs whose
# node sits 0.5 or 2.5 ms behind another give the host the same reads:
# bench/linemodels.py, ``behind``).
# Not counted while held (the line learns nothing: the hold's own reason says why) nor
# before the estimate locks; a reset, a release or an outage starts it over.
DRIFT_ERROR = FLOOR_NOISE / (WINDOW / 4)
"""How far from the crystal's true drift a line that saw its floor may be (above)."""

# What a line held over capacity may drift from (held_error). DRIFT_ERROR is the
# allowance of a line that has seen its floor only somewhere in the window; a line that
# was seeing its floor all along when held (within FLOOR_FRESH of the hold) has a drift
# measured far closer. Against the truth, over the sweep's runs whose every stream saw
# its floor in each 10 s (bench/sweep.py, 200 seeds of each line model, 120 s a run),
# no stream's error moved more than 0.051 ms in its run on gx2-sim's line, and 0.23 ms
# on the FIFO's: 1.9 ppm at most. HELD_DRIFT_ERROR allows 5; and the crystal may follow
# its temperature meanwhile at DRIFT_RATE, which is what the fit allows a settled drift
# (so 0.5 ms is reached after about 60 s held). Against the truth in the fault soak
# (bench/faultsoak.py), where DRIFT_ERROR said a held node's time may be off after 15 s
# and 98% of that WARN's time fell on samples within 0.2 ms: docs/performance-history.md.
# Those streams had fitted their drift over a whole window. One fitted over T < WINDOW
# seconds is held to DRIFT_ERROR's own reasoning at the base it has: off by FLOOR_NOISE
# over half of it, twice (4 FLOOR_NOISE / T; DRIFT_ERROR is that at T = WINDOW), whether
# or not the line was seeing its floor when held (held_drift_error). T counts only the
# seconds between fits that saw the floor (``_fitted_seen``): a fit over packets that
# all waited draws its slope from their waits (a line turning busy: half a second
# free, then every packet 2.5 to 3.4 ms behind another's, drew a drift 150 ppm off that
# 25 s of fitting would have allowed 80). And the drift's gap to its packets' own slope
# is kept through a reset, release or outage, as the drift is (a hold in a new line's
# first second had allowed none of a 65 ppm gap). The rule before allowed
# FLOOR_NOISE / T, at most DRIFT_ERROR: in the suite's fault soak an overload in the
# run's first minute held a drift fitted over about 40 s, 33 ppm off, and ``time`` went
# 3.7 ms off under an allowance under 0.5 ms; random lives of one node
# (bench/heldlives.py) found holds 1.2 ms past it. The step to HELD_DRIFT_ERROR at a
# window fitted on the floor is kept: 5 ppm is what was measured of such lines, and
# nothing of shorter ones (docs/performance-history.md measures the rules).
HELD_DRIFT_ERROR = 5e-6
FLOOR_FRESH = 10.0
"""Device seconds within which a line saw its floor for its drift to count as measured
when it is held."""


def held_drift_error(fitted: float, fresh: bool) -> float:
    """How far from the crystal's the drift of a held line may be, fitted on its floor
    for ``fitted`` device seconds, and ``fresh`` if it was seeing its floor when held
    (see HELD_DRIFT_ERROR)."""
    if fitted < SETTLE_SPAN:  # (not settled: a hold drops such a drift)
        return MAX_DRIFT
    if fitted < WINDOW:
        return min(MAX_DRIFT, 4 * FLOOR_NOISE / fitted)
    return HELD_DRIFT_ERROR if fresh else DRIFT_ERROR


# A gap: packets stop (an unplug, a radio out of range, a stream stopped) and come back
# within the window. The line is extrapolated across the gap at its drift, which is off
# by as much as a held line's may be (held_drift_error): a line whose drift was fitted
# on its floor over a window vouches for itself across a minute, one fitted over a few
# seconds not across the five of an unplug. In the suite's fault soak, a base station
# unplugged 6 s after the gateway started came back after 5 s with a line 1.0 ms late,
# locked and said OK. After such a gap the line is kept, as before, but is not locked
# for LOCK_SPAN (status, and health, say "not locked" for that second), while its fits
# take in the packets after the gap. Starting the line over instead (a first version)
# made ``time`` worse where the packets after the gap all waited (an outside review: a
# line then behind another node's packets went from 0.08 ms to 1.0 ms late), and a node
# polled every 5 s never locked: the rule is for a streaming line that was seeing its
# floor, and a gap of ten times its packets' spacing or more.
GAP_MIN = FLOOR_NOISE / MAX_DRIFT
"""Device seconds without a packet that any line vouches for itself across (2.5 s)."""
SPARSE = 10
"""A gap unlocks a line only if it is this many times the spacing of the two packets
before it: a streaming line's (a polled node's points are seconds apart)."""

Point = tuple[float, float]


def waited(arrival: float, line_free: float) -> bool:
    """Whether a packet that began on the serial line at ``arrival`` waited there
    behind the packet whose last byte the host read at ``line_free`` (host seconds): it
    began within the floor's noise of that one's end (see DRIFT_ERROR)."""
    return arrival - line_free < FLOOR_NOISE


@dataclass(frozen=True)
class Estimate:
    """What status shows of a node's clock: host time at device time 0 (on the clock
    the pairs came in), drift, the spread of recent delays above the line, and since
    when (host time) the estimate has been locked."""

    offset: float
    drift: float
    spread: float
    locked: bool
    locked_since: float | None


def _push(hull: list[Point], x: float, y: float) -> None:
    """Add (x, y), x not below any x in ``hull``, keeping ``hull`` a lower hull."""
    while hull:
        last_x, last_y = hull[-1]
        if x == last_x:  # (two records of one cycle: the lower one stays)
            if y >= last_y:
                return
            hull.pop()
            continue
        if len(hull) >= 2:
            x1, y1 = hull[-2]
            if (last_x - x1) * (y - y1) - (last_y - y1) * (x - x1) <= 0:
                hull.pop()  # (last_x, last_y) is not below the chord: not on the hull
                continue
        break
    hull.append((x, y))


class NodeClock:
    """The estimate for one node; :meth:`reset` when its timer restarts, :meth:`hold`
    and :meth:`release` as its serial line fills and has room again."""

    __slots__ = (
        "_block_start",
        "_blocks",
        "_current",
        "_drift",
        "_edge_gap",
        "_first",
        "_fitted",
        "_fitted_at",
        "_fitted_seen",
        "_floor_at",
        "_floor_drift",
        "_floor_offset",
        "_floor_seen",
        "_given",
        "_held_at",
        "_held_first",
        "_held_floor_age",
        "_held_fresh",
        "_held_gap",
        "_held_last",
        "_last",
        "_locked_since",
        "_offset",
        "_paused",
        "_points",
        "_relock_at",
        "_residuals",
        "_sightings",
        "_spacing",
        "_state",
        "floors_taken_back",
        "last_wait",
    )

    def __init__(self) -> None:
        self._drift = 0.0
        self._fitted = 0.0
        """Device seconds over which the drift has been fitted (kept through a reset:
        the drift is the crystal's)."""
        self._fitted_seen = 0.0
        """Of those, the seconds between fits that saw the floor: the drift's evidence
        (a fit over packets that all waited learns from their waits; see
        held_drift_error)."""
        self._edge_gap = 0.0
        """How far the drift is from the slope of the hull's edge it is drawn to, at the
        last fit: what the rate bound (or the clamp) holds it from its packets. Kept,
        with the drift, through a reset, release or outage until the next fit."""
        self._state = FRESH
        self._paused = False
        """Whether its points teach the line nothing for now (:meth:`pause`)."""
        self.floors_taken_back = 0
        """How many times a lock took back the floor its line had seen (_confirm_floor):
        what was judged from that floor meanwhile rests on waiting packets."""
        self.last_wait = 0.0
        """How far above the line the newest packet arrived (seconds): its wait, if the
        line stands on the floor; held, above the line kept (what a queue on the
        serial line is judged by: gateway.daemon.station.lineload)."""
        self._held_at = self._held_last = self._held_first = self._held_gap = 0.0
        self._held_floor_age: float | None = None
        """Device time of the newest packet when the line was last held, and of the
        newest since."""
        self._held_fresh = False
        """Whether the line was seeing its floor when held (within FLOOR_FRESH, locked,
        settled: held_drift_error)."""
        self._start_over()
        self._given: tuple[float, float] | None = None
        """The last (device, host) time given: times are strictly increasing (until a
        reset: a new power-up starts a new line)."""

    # -- the state machine: every change of state goes through _event -------------------

    def reset(self) -> None:
        """The node rebooted: its timer started again. The drift is kept (it is the
        crystal's); the line and the times given start over (held or not: a hold
        then places the new power-up at its packets' arrival, HELD_FRESH)."""
        self._event(RESET)

    def hold(self) -> None:
        """The serial line is over capacity: every packet from now on waits behind a
        backlog, and its delay says how long the queue is, not where the clock is. The
        line is kept as it is (extrapolated at its drift) and learns nothing until
        :meth:`release`; the estimate shows unlocked meanwhile. A drift fitted over too
        short a base line to be settled may already be the backlog's growth (it came
        with the first packets): it is dropped for the crystal's nominal rate."""
        self._event(HOLD)

    def release(self) -> None:
        """The line has room again: the estimate starts over from fresh packets (the
        drift, a settled one, kept), and ``time`` slews to it (SLEW)."""
        self._event(RELEASE)

    # A line young enough that its drift is not yet bound (fitted under SETTLE_SPAN)
    # draws its slope from the hull's edge across the window's middle, and a queue
    # growing under the packets reaches that middle after as many seconds as the line
    # was old when it began: the line then steps onto the queue's slope. The serial
    # line's judge confirms a queue only after CONFIRM bins of evidence
    # (gateway.daemon.station.lineload), so a line 3 s old when an overload began went
    # 0.5 ms late before its hold, unwarned (the suite's fault soak, CI of 45853d9:
    # 6% of the off samples; a line of 2 to 3 s, fed a queue growing at 0.26 s a
    # second, is 0.55 ms off by its hold at 3 s, and 0.09 paused from the first bin:
    # tests/aspp/test_clock.py). Pausing is no state of the estimate: the line stays
    # fitted and locked, and only stops taking points, until the evidence is either
    # confirmed (a hold, from the line as it stood) or gone (a host stall's backlog).
    def pause(self, paused: bool) -> None:
        """Whether the packets from now on teach the line nothing: the serial line shows
        a queue it has not yet confirmed. Only a fitted line is kept: a first packet
        still anchors one (FRESH, RELEASED: the packets after it then keep that
        anchor), and a held one learns nothing anyway."""
        self._paused = paused

    @property
    def paused(self) -> bool:
        return self._paused

    def _event(self, event: ClockEvent) -> None:
        """The one place the state changes: to what :func:`aspp.clockstate.after` says
        (which raises for an event the state does not take), with what the event does
        to the line. A hold keeps the line (and drops a drift not yet settled); a
        release or an outage starts the line over, its drift and the times given kept;
        a reset starts both over."""
        self._state = after(self._state, event)
        if event is HOLD:
            self._held_at = self._held_last = self._last
            # (locked: a sighting before the lock is not confirmed yet, _confirm_floor)
            self._held_gap = self._edge_gap
            self._held_floor_age = (self._last - self._floor_at
                                    if self._locked_since is not None else None)
            # (a drift at the clamp was drawn there by late packets: not the crystal's)
            if self._fitted < SETTLE_SPAN or abs(self._drift) >= MAX_DRIFT:
                self._offset += self._drift * self._last  # the same line where it is now
                self._drift = self._fitted = self._fitted_seen = self._held_gap = 0.0
                self._edge_gap = 0.0
            fresh = (self._locked_since is not None and self._fitted >= SETTLE_SPAN
                     and self._floor_seen and self._last - self._floor_at <= FLOOR_FRESH)
            self._held_fresh = fresh
        elif event is RESET:
            self._start_over()
            self._given = None
        elif event is not POINT:  # RELEASE, OUTAGE
            self._start_over()

    def _start_over(self) -> None:
        """No points: the line, its blocks and its lock are gone (drift and times given
        are the caller's to keep)."""
        self._blocks: deque[tuple[float, list[Point]]] = deque()
        self._current: list[Point] = []
        self._block_start = 0.0
        self._offset = 0.0
        self._fitted_at: float | None = None
        self._points = 0
        self._first = 0.0
        self._last = 0.0
        self._spacing = 0.0
        """Device seconds between the newest packet and the one before it."""
        self._relock_at = 0.0
        """Device time before which the line is not locked again after a gap it could
        not vouch for itself across (GAP_MIN)."""
        self._locked_since: float | None = None
        self._residuals: deque[float] = deque(maxlen=RESIDUALS)
        self._floor_at = 0.0
        """Device time of the last packet near the floor (see DRIFT_ERROR), and the
        line as it stood then."""
        self._floor_offset = 0.0
        self._floor_drift = 0.0
        self._floor_seen = False
        """Whether a packet has shown the floor since the line started (see floor_seen)."""
        self._sightings: list[Point] | None = []
        """Until the lock, each packet that showed the floor: judged again then (see
        _confirm_floor); None once locked."""

    # -- packets ---------------------------------------------------------------------------

    def update(self, device: float, host: float, waited: bool = False) -> float:
        """Add one packet: its device time and when it reached the host (seconds on a
        clock that never steps), and whether it :func:`waited` behind another on the
        serial line (it then shows no floor: see DRIFT_ERROR). Returns the host time at
        which a packet sent at ``device`` arrives with the least delay seen (the line
        evaluated there), or, if the line has just dropped below the last time given, a
        time advancing from that one at SLEW of the device's rate."""
        if self._state is not FITTED:
            return self._unfitted(device, host, waited)
        gap = device - self._last
        if gap < 0 or gap > WINDOW:
            if gap < 0:  # not in order (a reset missed): it says nothing
                return self._give(device, device + self._offset + self._drift * device)
            self._event(OUTAGE)  # after a long outage: the old points no longer bound
            return self._unfitted(device, host, waited)
        if gap > GAP_MIN and self._locked_since is not None and self._cannot_bridge(gap):
            self._locked_since = None  # (see GAP_MIN: said not locked for a second)
            self._relock_at = device + LOCK_SPAN
        if self._paused:  # (the line kept as it stands: see pause)
            # the newest packet still counted: a hold anchors there, the floor ages, and
            # the first packet after a pause is no gap; a line a gap unlocked (GAP_MIN)
            # fits its second after the pause
            self._spacing = gap
            self._last = device
            if self._locked_since is None and self._relock_at:
                self._relock_at = max(self._relock_at, device + LOCK_SPAN)
            line = self._offset + self._drift * device
            self.last_wait = host - device - line
            return self._give(device, device + line)
        y = host - device
        _push(self._current, device, y)
        self._points += 1
        self._spacing = gap
        self._last = device
        if device - self._block_start >= BLOCK:
            self._close_block(device)
        elif device - self._first < EARLY and (device - (self._fitted_at or 0.0) >= EARLY_STEP
                                               or y < self._offset + self._drift * device):
            self._fit()
        elif y < self._offset + self._drift * device:
            self._offset = y - self._drift * device  # lowered to it; refit at the block's end
        offset, drift = self._offset, self._drift
        line = offset + drift * device
        self.last_wait = residual = y - line
        self._residuals.append(residual)
        # the floor seen (see DRIFT_ERROR)
        if not waited and residual <= FLOOR_NOISE:
            self._floor_at, self._floor_offset, self._floor_drift = device, offset, drift
            self._floor_seen = True
            if self._sightings is not None:
                self._sightings.append((device, y))
        if self._locked_since is None and self._points >= LOCK_POINTS \
                and device - self._first >= LOCK_SPAN and device >= self._relock_at:
            self._locked_since = host
            self._confirm_floor()
        return self._give(device, device + line)

    def _cannot_bridge(self, gap: float) -> bool:
        """Whether a locked line cannot vouch for itself across ``gap`` device seconds
        without a packet (see GAP_MIN): streaming, seeing its floor, and its drift's
        allowance times the gap past the floor's noise."""
        fresh = self._floor_seen and self._last - self._floor_at <= FLOOR_FRESH
        return fresh and gap > SPARSE * self._spacing and \
            gap * held_drift_error(self._fitted_seen, True) > FLOOR_NOISE

    def _unfitted(self, device: float, host: float, waited: bool) -> float:
        """A packet with no line learning from it: the first of one (FRESH, RELEASED:
        it anchors the line at its arrival), or one while held (HELD: the line kept
        says; HELD_FRESH: the arrivals' floor, lowered to this one if it came faster)."""
        state = self._state
        y = host - device - self._drift * device
        if state in HELD_STATES:
            self._held_last = device
            self._event(POINT)
            if state is HELD_FRESH:
                if not self._points:
                    self._held_first = y
                if not self._points or y < self._offset:
                    self._offset = y
                self._points += 1
                # (against its first packet: the floor follows the fastest, and a
                # queue draining under it shows as its packets coming ever earlier)
                self.last_wait = y - self._held_first
            else:
                self.last_wait = y - self._offset
            return self._give(device, device + self._offset + self._drift * device)
        self._event(POINT)  # -> FITTED
        self.last_wait = 0.0
        _push(self._current, device, host - device)
        self._points = 1
        self._first = self._block_start = self._last = device
        self._offset = y
        self._residuals.append(0.0)
        self._floor_at, self._floor_offset, self._floor_drift = device, y, self._drift
        self._floor_seen = not waited  # (the line's anchor: a floor only if it did not wait)
        if not waited:
            self._sightings = [(device, host - device)]
        return self._give(device, host)

    def _confirm_floor(self) -> None:
        """At the lock, the floor's sightings judged again against the line its second
        of packets drew. Before it, the line rests on the few packets there are, and
        one the host read later than the packet before it by more than FLOOR_NOISE
        lies on it though it waited: a gateway busy starting up read node 77 of
        tests/e2e/test_clock_floor.py (every packet behind 76's) so at its first or
        second packet in one run of ten, and status said its floor seen for good. Such
        a packet lies above the line drawn since by what the host added, and so more
        than FLOOR_NOISE above it; a true sighting stays within it. (The sightings
        still count as they come until then: the line's judge takes a node's floor
        from its first second, :mod:`gateway.daemon.station.lineload`.)"""
        if self._sightings is None:  # (locked again after a gap: judged at the first)
            return
        sightings, self._sightings = self._sightings, None
        offset, drift = self._offset, self._drift
        kept = [x for x, y in sightings if y - (offset + drift * x) <= FLOOR_NOISE]
        if kept:
            self._floor_at, self._floor_offset, self._floor_drift = kept[-1], offset, drift
        elif self._floor_seen:  # (none held: never seen, counted from the first packet)
            self._floor_seen = False
            self.floors_taken_back += 1
            self._floor_at, self._floor_offset, self._floor_drift = self._first, offset, drift

    def _give(self, device: float, time: float) -> float:
        given = self._given
        if given is not None and device >= given[0]:
            # strictly above the floor by a double's step there, not by a fixed
            # nanosecond: that is lost in rounding once the host clock reads 2**24 s
            # (a monotonic clock after 194 days up; the UNIX clock always, which is why
            # gateway.daemon.station.nodes keeps the promise again after converting to it)
            elapsed = device - given[0]
            floor = given[1] + SLEW * elapsed
            if time <= floor:
                time = math.nextafter(floor, math.inf)
            elif time > given[1] + (1 + SLEW) * elapsed:
                time = max(given[1] + (1 + SLEW) * elapsed, math.nextafter(floor, math.inf))
        self._given = (device, time)
        return time

    def _close_block(self, device: float) -> None:
        self._blocks.append((self._block_start, self._current))
        self._current = []
        self._block_start = device
        while self._blocks and self._blocks[0][1][-1][0] < device - WINDOW:
            self._blocks.popleft()
        self._first = self._blocks[0][1][0][0]
        self._fit()

    def _fit(self) -> None:
        """The line below every point that supports the hull at the window's middle (its
        slope drawn towards the edge there at the rate SETTLE_SPAN's comment says)."""
        hull: list[Point] = []
        for _, vertices in self._blocks:
            for x, y in vertices:
                _push(hull, x, y)
        for x, y in self._current:
            _push(hull, x, y)
        if hull[-1][0] - hull[0][0] < LOCK_SPAN:  # too short a base line for a slope
            self._offset = min(y - self._drift * x for x, y in hull)
            return
        # (issue 32: keeping the drift while the line rested in the window's middle
        # half, f9a36a2, broke ``time`` on a FIFO line: docs/performance-history.md)
        middle = (hull[0][0] + hull[-1][0]) / 2
        edge = min(max(bisect.bisect_left(hull, (middle,)), 1), len(hull) - 1)
        (x1, y1), (x2, y2) = hull[edge - 1], hull[edge]
        slope = (y2 - y1) / (x2 - x1)
        drift = max(-MAX_DRIFT, min(MAX_DRIFT, slope))
        now = hull[-1][0]
        step = 0.0 if self._fitted_at is None else max(now - self._fitted_at, 0.0)
        self._fitted += step
        if self._floor_seen and self._fitted_at is not None \
                and self._floor_at > self._fitted_at:  # (a sighting since the last fit)
            self._fitted_seen += step
        if self._fitted >= SETTLE_SPAN and abs(self._drift) < MAX_DRIFT:  # (not at the clamp)
            room = max(DRIFT_RATE, FLOOR_NOISE / self._fitted ** 2) * step
            drift = max(self._drift - room, min(self._drift + room, drift))
        self._fitted_at = now
        self._drift = drift
        self._edge_gap = abs(slope - drift)
        self._offset = min(y - drift * x for x, y in hull)

    def device_at(self, host: float) -> float | None:
        """The device time of a packet that reaches the host at ``host`` with the least
        delay seen (the line there), or None before the estimate is locked: what the
        timer unwrapper judges a reading by (:class:`aspp.timing.TimerUnwrapper`). A
        line not locked for a second after a gap (GAP_MIN) was locked, and still judges
        (a reboot in a second gap within that second went unseen without it)."""
        if self._state is not FITTED or (self._locked_since is None and not self._relock_at):
            return None
        return (host - self._offset) / (1 + self._drift)

    @property
    def points(self) -> int:
        """Packets the line (or, held with none, the arrivals' floor) stands on: since
        the last reset, release or outage."""
        return self._points

    @property
    def state(self) -> ClockState:
        return self._state

    @property
    def locked(self) -> bool:
        """Whether a second of packets has been fitted since the last reset, and the
        line is not held (:meth:`hold`)."""
        return self._locked_since is not None and self._state is FITTED

    @property
    def held(self) -> bool:
        return self._state in HELD_STATES

    def held_error(self) -> float | None:
        """How far ``time`` may have gone from the line kept since the hold (seconds):
        its drift's uncertainty times the device seconds held (held_drift_error: by
        the base it was fitted over and whether the line was seeing its floor, with the
        crystal's own wander for one that was; a drift not settled was dropped for the
        nominal rate: any a crystal can have), and how far the drift stood from its
        packets' own slope; inf with no line of this power-up to keep (HELD_FRESH:
        placed at the arrivals, late by the queue); None unless held."""
        if self._state is HELD_FRESH:
            return math.inf
        if self._state not in HELD_STATES:
            return None
        held = max(self._held_last - self._held_at, 0.0)
        gap = self._held_gap * held  # (the packets' own slope, which the bound held off)
        drift_error = held_drift_error(self._fitted_seen, self._held_fresh) * held
        if self._held_fresh:  # (and the crystal following its temperature meanwhile)
            drift_error += DRIFT_RATE * held * held / 2
        return gap + drift_error

    @property
    def held_floor_age(self) -> float | None:
        """While held: the floor's age when the hold began (see floor_age; None if the
        line was not locked then, or unless held). A line held with its floor long
        unseen was already as late as that says, and the hold keeps it so."""
        return self._held_floor_age if self._state in HELD_STATES else None

    @property
    def floor_age(self) -> float | None:
        """Device seconds from the last packet near the floor to the newest packet
        (see DRIFT_ERROR); None unless locked (before the lock, or held)."""
        return self._last - self._floor_at if self.locked else None

    @property
    def floor_seen(self) -> bool:
        """Whether a packet has shown the floor since the line started (a reset, release
        or outage): a line that never saw it is late by a wait that no packet shows, and
        :meth:`late_bound` counts only from its first packet. Before the lock it says
        what the packets so far show, and the lock may take it back (_confirm_floor)."""
        return self._floor_seen

    def late_bound(self) -> float | None:
        """How much later than where the floor was last seen ``time`` may be, at the
        newest packet (seconds, see DRIFT_ERROR); None unless locked."""
        age = self.floor_age
        if age is None:
            return None
        x = self._last
        moved = (self._offset + self._drift * x
                 - (self._floor_offset + self._floor_drift * x))
        return abs(moved) + DRIFT_ERROR * age + FLOOR_NOISE

    def estimate(self) -> Estimate:
        """The current estimate (for status)."""
        ordered = sorted(self._residuals)
        spread = ordered[int(0.9 * (len(ordered) - 1))] if ordered else 0.0
        return Estimate(self._offset, self._drift, spread, self.locked,
                        None if self.held else self._locked_since)
