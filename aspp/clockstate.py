"""The states of a node's clock estimate (:class:`aspp.clock.NodeClock`) and the one table
of what moves it from one to another. Every change of state goes through :func:`after`;
an event a state does not take raises :class:`~aspp.errors.ClockStateError` (a release
with no hold is the caller's bug, not something to guess about).

Two things decide what a record's ``time`` can be: whether the estimate has a line of
its own (fitted under this power-up's packets), and whether the serial line is over
capacity (every packet's arrival then says how long the base station's queue is, not
where the node's clock is). The states are those two, plus what the times given so far
bind (``time`` never steps: a new line is followed at the SLEW from the last time
given, except across a reboot, which starts a new line):

- FRESH: no line and no hold. The next point anchors a line at its own arrival.
- FITTED: a line under this power-up's packets, each one refining it.
- HELD: over capacity, with a line: it is kept where it was, extrapolated at its drift;
  packets teach it nothing.
- HELD_FRESH: over capacity with no line of this power-up's to keep: the node rebooted
  (or sent its first timed record) while the line was full. Its device seconds are on
  no line yet, so ``time`` is the arrivals' own floor: the least host - device over its
  packets, at the drift kept. That is late by the queue the fastest packet waited behind
  (at most the base station's buffer: 0.36 s of line for gx2-sim's 4 KiB), never by an
  offset of another power-up or of none.
- RELEASED: no line and no hold, but times given before it (the hold just ended, or an
  outage longer than the window left the old points meaning nothing): the estimate
  starts over from fresh packets as FRESH does, and ``time`` continues from the last
  one given at the SLEW, not by a step.

The events: HOLD and RELEASE (the line over capacity, then with room again), RESET (the
node rebooted: its timer restarted), POINT (a packet, in order), OUTAGE (a packet more
than the window after the last: the old points no longer bound). A timer's wrap is no
event here: :class:`aspp.timing.TimerUnwrapper` unwraps it before the clock sees any
device time.

Why the rows are what they are:

- A RESET never keeps a line (its offset is the old power-up's) and never maps device
  seconds through an offset that nothing set: while held it goes to HELD_FRESH, whose
  first point places the node's time at its arrival. (Issue 31: a reset while held
  zeroed the offset and kept the hold, so ``time`` was the node's own seconds read as
  the host's monotonic clock, off by the host's uptime; a first point while held did
  the same.) A RESET also forgets the times given: the new power-up's line is not bound
  to the old one's.
- A HOLD keeps a fitted line (HELD); with none, the arrivals' floor is the best there is
  (HELD_FRESH). Either way a drift fitted over too short a base line to be settled is
  dropped for the crystal's nominal rate: it may be the backlog's growth.
- A RELEASE starts over from fresh packets whichever line was held (RELEASED): the held
  line, or the floor, carried the queue.
- HOLD on a hold, RELEASE with none, OUTAGE while held or with no point yet: not taken.
  (While held no point is learnt, so there is no outage to judge.)
"""

from __future__ import annotations

from enum import StrEnum

from .errors import ClockStateError


class ClockState(StrEnum):
    FRESH = "fresh"
    FITTED = "fitted"
    HELD = "held"
    HELD_FRESH = "held fresh"
    RELEASED = "released"


class ClockEvent(StrEnum):
    HOLD = "hold"
    RELEASE = "release"
    RESET = "reset"
    POINT = "point"
    OUTAGE = "outage"


FRESH, FITTED, HELD, HELD_FRESH, RELEASED = ClockState
HOLD, RELEASE, RESET, POINT, OUTAGE = ClockEvent

TRANSITIONS: dict[tuple[ClockState, ClockEvent], ClockState] = {
    (FRESH, HOLD): HELD_FRESH,
    (FRESH, RESET): FRESH,
    (FRESH, POINT): FITTED,
    (FITTED, HOLD): HELD,
    (FITTED, RESET): FRESH,
    (FITTED, POINT): FITTED,
    (FITTED, OUTAGE): RELEASED,
    (HELD, RELEASE): RELEASED,
    (HELD, RESET): HELD_FRESH,
    (HELD, POINT): HELD,
    (HELD_FRESH, RELEASE): RELEASED,
    (HELD_FRESH, RESET): HELD_FRESH,
    (HELD_FRESH, POINT): HELD_FRESH,
    (RELEASED, HOLD): HELD_FRESH,
    (RELEASED, RESET): FRESH,
    (RELEASED, POINT): FITTED,
}
"""(state, event) -> the state after it; a pair not here is not taken."""

HELD_STATES = frozenset({HELD, HELD_FRESH})
"""The states in which the serial line is over capacity."""


def after(state: ClockState, event: ClockEvent) -> ClockState:
    """The state ``event`` leads to from ``state``; ClockStateError if it is not taken."""
    try:
        return TRANSITIONS[state, event]
    except KeyError:
        raise ClockStateError(f"clock estimate: {event} is not taken when {state}") from None
