"""A stream's rows counted a batch at a time: what :meth:`.losses.Stream.add` decides
row by row (the period the shortest step among WINDOW either side, if it is also the
most common; a restart where the timer or ``seq`` says so), decided with numpy over a
batch, the stream left in the very state its row-by-row adds would leave it in, so the
two can follow each other (a continuous-mode reply or a damaged stretch is given to the
stream between two batches, as it is between two rows; tests/recording/test_batchsteps.py
holds the two against each other).

Why: the row-by-row stream costs about 10 us a row in Python, more than everything else
a columnar export does with a row (bench/exportformats.py). A batch whose rows are not
all timed, or whose steps are many (records polled now and then), is added row by row.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from aspp.timing import MAX_DIVIDER, MIN_DIVIDER, TICKS_PER_CLOCK, TICKS_PER_SECOND, TIMER_MODULUS

from .losses import WINDOW, Counted, Stream, _Last, _Row

DISTINCT = 48
"""More distinct steps than this around a batch: counted row by row (a cost per
distinct step and row here)."""
NONE = -1
"""An absent integer in the arrays below (timer, seq; lost: not known)."""


@dataclass
class Rows:
    """A batch of one stream's rows as the counting needs them: ``device_time`` (s),
    the raw ``timer`` and ``seq`` (NONE: absent), the node's messages so far, this one
    included (``count``), and the row's ``time`` (else ``host_time``; NaN: neither)."""

    device: np.ndarray
    timer: np.ndarray
    seq: np.ndarray
    count: np.ndarray
    time: np.ndarray


@dataclass
class Decided:
    """Rows decided, in order: what :class:`.losses.Counted` holds, as arrays (``items``:
    which rows, numbered as given to :func:`add_many`)."""

    items: list[np.ndarray] = field(default_factory=list)
    lost: list[np.ndarray] = field(default_factory=list)
    gateway: list[np.ndarray] = field(default_factory=list)
    unread: list[np.ndarray] = field(default_factory=list)
    down: list[np.ndarray] = field(default_factory=list)

    def extend(self, counted: list[Counted[int]]) -> None:
        if counted:
            self.items.append(np.array([c.item for c in counted], np.int64))
            self.lost.append(np.array([NONE if c.lost is None else c.lost for c in counted],
                                      np.int64))
            self.gateway.append(np.array([c.gateway for c in counted], np.int64))
            self.unread.append(np.array([c.unread for c in counted], np.int64))
            self.down.append(np.array([c.down for c in counted], np.int64))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(items, lost, gateway, unread, down), emptied."""
        def joined(parts: list[np.ndarray]) -> np.ndarray:
            whole = np.concatenate(parts) if parts else np.zeros(0, np.int64)
            parts.clear()
            return whole
        return (joined(self.items), joined(self.lost), joined(self.gateway),
                joined(self.unread), joined(self.down))


def add_many(stream: Stream[int], rows: Rows, decided: Decided, first: int = 0) -> None:
    """Add the batch's rows (numbered from ``first``) to ``stream``, the rows decided
    (in order) to ``decided``, as its adds would decide them one by one."""
    device = rows.device
    if not len(device):
        return
    if not (np.all(np.isfinite(device)) and np.all(np.abs(device) < 2.0 ** 52
                                                   / TICKS_PER_SECOND)):
        _by_rows(stream, rows, decided, first)  # (a row without device time is decided at once)
        return
    ticks = np.rint(device * TICKS_PER_SECOND).astype(np.int64)  # round(), half to even
    n = len(ticks)
    last = stream._last
    before = last if last is not None else _Last(0, None, None, 0, None)
    prev = {name: np.empty(n, kind) for name, kind in (
        ("ticks", np.int64), ("timer", np.int64), ("seq", np.int64), ("count", np.int64),
        ("time", np.float64))}
    for name, values, head in (
            ("ticks", ticks, before.ticks), ("timer", rows.timer, before.timer),
            ("seq", rows.seq, before.seq), ("count", rows.count, before.count),
            ("time", rows.time, before.time)):
        prev[name][1:] = values[:-1]
        prev[name][0] = (np.nan if name == "time" else NONE) if head is None else head
    restarted = np.zeros(n, bool)
    restarted[0] = last is None or stream._unknown
    seq, timer = rows.seq, rows.timer
    both_seq = (seq != NONE) & (prev["seq"] != NONE)
    restarted |= (ticks < prev["ticks"]) | (both_seq & (seq <= prev["seq"]))
    both_timer = (timer != NONE) & (prev["timer"] != NONE)
    apart = (ticks - prev["ticks"] - (timer - prev["timer"])) % TIMER_MODULUS
    restarted |= both_timer & (np.minimum(apart, TIMER_MODULUS - apart) > TICKS_PER_CLOCK)
    step = np.rint((ticks - prev["ticks"]) / TICKS_PER_CLOCK).astype(np.int64)
    valid = (step >= MIN_DIVIDER) & ~restarted
    distinct = np.unique(np.concatenate([np.array(stream._behind, np.int64), step[valid]]))
    if len(distinct) > DISTINCT:
        _by_rows(stream, rows, decided, first)
        return
    batch = _Batch(first, step, valid, np.where(
        both_seq & (seq > prev["seq"]),
        np.maximum(0, (seq - prev["seq"]) - (rows.count - prev["count"])), 0),
        prev["time"], rows.time, np.zeros(n, bool))
    batch.unread[0] = stream._unread  # (a damaged stretch just before the batch)
    bounds = [0, *np.flatnonzero(restarted).tolist(), n]
    for low, high in itertools.pairwise(bounds):
        if low == high:
            continue
        if restarted[low]:  # (as Stream.add: the rows before decided on what came)
            decided.extend(stream.flush())
            stream._behind.clear()
            stream._window.clear()
            decided.extend([Counted(first + low, None, 0)])
            stream._last = _last_of(rows, ticks, low)
            low += 1
        if low < high:
            _segment(stream, batch, low, high, final=high < n, decided=decided)
            stream._last = _last_of(rows, ticks, high - 1)
    stream._replied = stream._unknown = stream._unread = False


@dataclass
class _Batch:
    first: int
    step: np.ndarray
    valid: np.ndarray
    gateway: np.ndarray
    """The node's messages missing by ``seq`` since the row before."""
    before: np.ndarray
    """The time of the row before (NaN: none)."""
    time: np.ndarray
    unread: np.ndarray
    """A stretch of the recording that could not be read lies just before the row."""


def _last_of(rows: Rows, ticks: np.ndarray, i: int) -> _Last:
    timer, seq, time = int(rows.timer[i]), int(rows.seq[i]), float(rows.time[i])
    return _Last(int(ticks[i]), None if timer == NONE else timer,
                 None if seq == NONE else seq, int(rows.count[i]),
                 None if time != time else time)


def _segment(stream: Stream[int], batch: _Batch, low: int, high: int, final: bool,
             decided: Decided) -> None:
    """Rows ``low`` to ``high`` of the batch (no restart among them), after the
    stream's pending rows: those whose window is whole decided (all, if ``final``: a
    restart follows), the rest left pending."""
    carried = list(stream._pending)
    steps = np.concatenate([
        np.array([NONE if r.step is None else r.step for r in carried], np.int64),
        np.where(batch.valid[low:high], batch.step[low:high], NONE)])
    m = len(steps)
    decide = m if final else max(0, m - stream.ahead)
    behind = np.array(stream._behind, np.int64)
    timed = steps != NONE
    if decide:
        # row j's window: up to WINDOW decided steps behind it, and the steps of rows
        # j .. j + ahead (pending when it is decided; to the end if final), counted
        # for each distinct step by prefix sums
        sequence = np.concatenate([behind, steps[timed]])
        values = np.unique(sequence)
        j = np.arange(decide)
        rank = len(behind) + np.concatenate([[0], np.cumsum(timed)])[:decide]
        stop = np.minimum(j + stream.ahead + 1, m)
        totals = np.empty((len(values), decide), np.int64)
        for k, value in enumerate(values):
            in_rows = np.concatenate([[0], np.cumsum(steps == value)])
            in_sequence = np.concatenate([[0], np.cumsum(sequence == value)])
            totals[k] = (in_rows[stop] - in_rows[j] + in_sequence[rank]
                         - in_sequence[np.maximum(0, rank - WINDOW)])
        if len(values):
            smallest = np.argmax(totals > 0, axis=0)
            shortest = values[smallest]
            is_period = (shortest <= MAX_DIVIDER) & (
                totals[smallest, j] >= totals.max(axis=0))
        else:  # (no step among them: every row a short one)
            shortest, is_period = np.zeros(decide, np.int64), np.zeros(decide, bool)
        mine = steps[:decide]
        counted = timed[:decide]
        period = np.where(is_period & counted, shortest, 0)
        lost = np.where(period > 0, np.maximum(
            0, np.rint(mine / np.where(period > 0, period, 1)) - 1), 0).astype(np.int64)
        gaps = np.concatenate([np.array([r.gateway for r in carried], np.int64),
                               batch.gateway[low:high]])[:decide]
        unread = np.concatenate([np.array([r.unread for r in carried], bool),
                                 batch.unread[low:high]])[:decide] & counted
        spent = np.where(unread, 0, np.minimum(lost, gaps))
        down = np.zeros(decide, np.int64)
        spans = [r.span for r in carried] + [None] * (high - low)
        for i in np.flatnonzero((lost > spent) & ~unread & counted):
            i = int(i)
            span = spans[i] if i < len(carried) else _span(batch, low + i - len(carried))
            stream.period = int(period[i]) or None
            down[i] = stream._down(span, int(lost[i] - spent[i]))
        decided.items.append(np.concatenate([
            np.array([r.item for r in carried], np.int64),
            np.arange(batch.first + low, batch.first + high)])[:decide])
        decided.lost.append(lost)
        decided.gateway.append(spent)
        decided.unread.append(np.where(unread, lost, 0))
        decided.down.append(down)
        last_timed = np.flatnonzero(counted)
        if len(last_timed):
            value = int(period[last_timed[-1]])
            stream.period = value or None
        stream._behind = deque([*stream._behind, *mine[counted].tolist()][-WINDOW:])
    pending: list[_Row[int]] = carried[decide:]
    for b in range(low + max(0, decide - len(carried)), high):
        item = batch.first + b
        pending.append(_Row(item, int(batch.step[b]), None, int(batch.gateway[b]),
                            bool(batch.unread[b]), _span(batch, b))
                       if batch.valid[b] else _Row(item, None, 0, 0))
    stream._pending = deque(pending)
    window: dict[int, int] = {}
    for value in [*stream._behind, *(r.step for r in pending if r.step is not None)]:
        window[value] = window.get(value, 0) + 1
    stream._window = window


def _span(batch: _Batch, b: int) -> tuple[float, float] | None:
    before, at = float(batch.before[b]), float(batch.time[b])
    return None if before != before or at != at else (before, at)


def _by_rows(stream: Stream[int], rows: Rows, decided: Decided, first: int) -> None:
    """The batch added row by row, as :class:`.losses.Stream` takes rows."""
    for item, (device, timer, seq, count, time) in enumerate(zip(
            rows.device.tolist(), rows.timer.tolist(), rows.seq.tolist(),
            rows.count.tolist(), rows.time.tolist(), strict=True), first):
        payload = {"device_time": None if device != device else device,
                   "timer": None if timer == NONE else timer,
                   "seq": None if seq == NONE else seq,
                   "time": None if time != time else time}
        decided.extend(stream.add(payload, item, count))


def flush(stream: Stream[int], decided: Decided) -> None:
    """The rows still pending, decided on what came (the end)."""
    decided.extend(stream.flush())
