"""A node's life: what it is doing (one :class:`State`, changed only by the transitions
here), what it should be doing (its configured stream and the operator's intent), and
the counters and payload of every record it sends.

Who calls the transitions: the supervisor (arming, recovery, operator intent) and the
per-record tally (a silent stream that resumes). Nothing else assigns a state.

:meth:`Node.tally` runs for every record: plain attributes and one dict, no pydantic,
no copies.
"""

from __future__ import annotations

import itertools
import math
import time
from enum import StrEnum
from typing import Any, NamedTuple

from aspp.clock import FLOOR_NOISE, NodeClock
from aspp.events import LINK_QUALITY
from aspp.orientation import euler_from_matrix, quaternion_from_matrix
from aspp.records import ORIENTED, Record
from aspp.timing import (
    BITS_PER_BYTE,
    CLOCK_HZ,
    DEFAULT_DIVIDER,
    TimerUnwrapper,
    data_rate,
    sample_period,
    valid_divider,
)
from gateway.common.topics import default_station_name

from ..config import FLOOR_UNSEEN_S, NodeEntry
from .lineload import Waited

RATE_WINDOW = 2.0
"""Seconds over which the record rate is measured."""
SILENCE_MIN = 1.0
SILENCE_PERIODS = 10
"""A stream with no record for this many sample periods (and at least SILENCE_MIN
seconds) has fallen silent: the node rebooted with its discovery packet lost, or went
out of range."""
STEPS_CHECKED = 32
"""Timer steps of a stream compared before its divider is corrected from them (a real
node may apply a new divider only after a power cycle, whatever its EEPROM says)."""
_NO_STEP = 1 << 62
"""The shortest step before any step is seen: longer than any."""
TIME_NOISE = 1e-3
"""Seconds by which a record's ``time`` may come out below the last one's from the
conversion to UNIX seconds alone (see :meth:`Node._after_last_time`); a larger fall is
a step of the host's clock, which ``time`` follows."""
OFF = "off"
"""The desired stream of a node an operator stopped: it is kept stopped."""


class State(StrEnum):
    UNKNOWN = "unknown"
    """Not heard of yet: the base station has not been open since the gateway started."""
    POLLED = "polled"
    """Streams nothing the gateway knows of; answers commands."""
    ARMING = "arming"
    """Its desired stream is being started."""
    STREAMING = "streaming"
    UNREACHABLE = "unreachable"
    """Did not answer while being armed; tried again after a backoff."""
    SILENT = "silent"
    """Its stream stopped arriving (out of range, or a reboot whose discovery was lost)."""
    REBOOTED = "rebooted"
    """Announced a power-up: whatever it streamed is gone."""
    STOPPING = "stopping"
    """A stop of its stream is under way."""
    BUSY = "busy"
    """A command that needs it quiet is running (a bias capture, a self-test): its
    stream is stopped until the command ends."""
    LINK_DOWN = "link down"
    """The base station is gone."""


class Delivery(NamedTuple):
    """A reply as the operations see it: the decoded record and its published payload."""

    record: Record
    payload: dict[str, Any]


_EPOCHS = itertools.count()


class Node:
    """One configured node."""

    def __init__(self, config: NodeEntry, *, byte_time: float = BITS_PER_BYTE / 115200,
                 latency: float = 0.0, station: str | None = None,
                 floor_unseen_s: float = FLOOR_UNSEEN_S) -> None:
        self.config = config
        self.station = station or default_station_name(0)
        """The name of the base station it is configured on (each record carries it)."""
        self.clock = NodeClock()
        """Where its timer falls on the host's clock (see :mod:`aspp.clock`)."""
        self._byte_time = byte_time
        """Seconds a byte takes on the serial line (10 bits at the baud rate)."""
        self.floor_unseen_s = floor_unseen_s
        """How long its clock may go without seeing its floor before it is a WARN, and
        status gives how late ``time`` may be (health.floor_unseen_s)."""
        self._latency = latency
        """Seconds from a sample to its packet leaving the base station, at the least:
        the radio's part, which the host cannot see (base_station.latency_ms)."""
        self.address = config.address
        self.name = config.name
        self.label = config.label
        self.desired: str | None = config.stream
        """What the node should stream: a record name, OFF (an operator stopped it), or
        None (nothing asked: it is left as it is). The configuration's ``stream`` until
        an operator's start or stop replaces it."""
        self._state = State.UNKNOWN
        self.record: str | None = None
        """The record it streams, as far as the gateway knows."""
        self._unwrapper = TimerUnwrapper(expect=self.clock.device_at)
        """Its timer unwrapped, each reading judged against the clock's line (the least
        delay seen): a reading far from it is a reboot unless it is a backlog read late
        (:mod:`aspp.timing`), whose first step the divider bounds (``divider``)."""
        self.divider = DEFAULT_DIVIDER
        self.seq = 0
        self.packets = 0
        self.lost_radio = 0
        self.lost_station_down = 0
        """Samples of its stream missed while its base station was down (unplugged, the
        port lost): no radio's fault, so not ``lost_radio``."""
        self.lost_gateway = 0
        self.reboots = 0
        self.silences = 0
        self.lqi: int | None = None
        self.rssi: int | None = None
        self.last_seen: float | None = None
        self.rate_hz = 0.0
        self.unusual = False
        """Whether its last record needs the supervisor's look (see :meth:`tally`)."""
        self.timer_reset = False
        """Its timer went back with no discovery packet to announce it: a reboot the
        supervisor has not dealt with yet (see :meth:`take_timer_reset`)."""
        self._reboot_announced = False
        """A discovery packet said the node rebooted, and its timer has not shown it yet
        (see :meth:`TimerUnwrapper.expect_reset`): the reset to come is not counted."""
        self._least_wait = math.inf
        """The least wait above its clock's line of its records since :meth:`take_wait`:
        what its serial line's queue is judged by (:mod:`.lineload`)."""
        self._epoch = next(_EPOCHS)
        """Its line's: new at each power-up, and for each Node made (a node a reload
        removed and added again starts its device time over), and when its clock took
        back the floor it had seen (the line's judge took floor bins from packets that
        waited meanwhile): waits are compared within one."""
        self._floors_taken_back = 0
        self._last_stream_device: float | None = None
        self._down_from: tuple[float, float] | None = None
        """Its stream's last record before its base station went down, until the
        stream's first record after: (device time, time.monotonic() it came)."""
        self._back_at: float | None = None
        """time.monotonic() when its base station came back, since it went down."""
        self._last_time = -math.inf
        """The last ``time`` published: each one after it is greater."""
        self._steps = 0
        self._shortest_step = _NO_STEP
        self._stream_seen = 0.0
        """time.monotonic() of the last record of the stream (or of its start)."""
        self.stream_started = 0.0
        """time.monotonic() when its stream last started, or resumed after a silence:
        its rate and clock are judged only a while after (see :mod:`.health`)."""
        self.trouble: str | None = None
        """How it last failed ("unreachable", "silent"), until it does what it should
        again: a node being armed once more after a failure is still in trouble."""
        self._window_start = 0.0
        self._window_count = 0

    @property
    def state(self) -> State:
        return self._state

    @property
    def divider(self) -> int:
        """Its calculation-cycle divider: its stream's rate, and the sample period its
        timer steps by (what tells a backlog read late from a reboot)."""
        return self._divider

    @divider.setter
    def divider(self, divider: int) -> None:
        self._divider = divider
        self._unwrapper.late_step = SILENCE_PERIODS * sample_period(divider)

    @property
    def period(self) -> float:
        return sample_period(self._divider)

    @property
    def expected_hz(self) -> float | None:
        """The rate its stream runs at, or None when it streams nothing."""
        if self._state in (State.STREAMING, State.SILENT) and self.record is not None:
            return data_rate(self.divider)
        return None

    @property
    def silence_limit(self) -> float:
        return max(SILENCE_MIN, SILENCE_PERIODS * self.period)

    # -- the per-record path -------------------------------------------------------------

    def tally(self, raw: bytes, record: Record, host_time: float,
              monotonic: float, line_free: float = -math.inf) -> dict[str, Any]:
        """Count one record of this node (seq, packets, link quality, rate, device time,
        sample time, samples lost over the air) and return its published payload. ``raw``
        is the packet it came in, read at ``host_time`` (UNIX) and ``monotonic``;
        ``line_free``: when (monotonic) the packet before it on the line was read, to
        judge whether it waited behind that one (:func:`aspp.clock.waited`)."""
        self.seq = seq = self.seq + 1
        self.packets += 1
        self.lqi, self.rssi = lqi, rssi = LINK_QUALITY.unpack_from(raw, len(raw) - 4)
        self.last_seen = host_time
        self._window_count += 1  # the record rate, measured over RATE_WINDOW
        if host_time - self._window_start >= RATE_WINDOW:
            self._close_rate_window(host_time)
        spec = record.spec
        name = spec.name
        # zip without strict= (decode() made the lengths equal): the keyword alone costs
        # 2.3% of the instructions a record takes (bench/instructions.py)
        payload = dict(zip(spec.field_names, record.values),  # noqa: B905
                       node=self.address, record=name, command=spec.code, seq=seq,
                       host_time=host_time, lqi=lqi, rssi=rssi, station=self.station)
        if name in ORIENTED:  # (its angles and quaternion: aspp.records.DERIVED_FROM_MATRIX)
            matrix = payload["orientation"]
            payload["roll"], payload["pitch"], payload["yaw"] = euler_from_matrix(matrix)
            payload["quaternion"] = quaternion_from_matrix(matrix)
        is_stream = name == self.record
        timer = payload.get("timer")
        if timer is not None:
            # the clock (and the unwrapper, judging by it) runs on the monotonic clock, fed
            # when the packet began to reach the host (its own bytes on the line before
            # the read); the sample was taken the radio's latency before it left, and
            # goes out on the UNIX clock of the read, so a step of that clock moves it
            # by the step and no more
            arrival = monotonic - len(raw) * self._byte_time
            unwrapper = self._unwrapper
            payload["device_time"] = device = unwrapper.update(timer, arrival)
            if unwrapper.last_was_reset:
                self._timer_restarted()
            # whether it waited behind the packet before it on the line (then it shows no
            # floor): aspp.clock.waited, inlined here where the arrival is known.
            # Instructions a record (bench/instructions.py): 91,574 without the judgement,
            # 92,900 with the call in the reader, 92,532 inlined there, 92,001 here; the
            # line's least wait beside it (issue 38): 91,683 before, 92,332 after
            clock = self.clock
            sampled = (clock.update(device, arrival, arrival - line_free < FLOOR_NOISE)
                       - self._latency + host_time - monotonic)
            if clock.last_wait < self._least_wait:  # (the line's queue: take_wait)
                self._least_wait = clock.last_wait
            if sampled <= self._last_time:
                sampled = self._after_last_time(sampled)
            payload["time"] = self._last_time = sampled
            if is_stream:
                self._count_gaps(device)
        if is_stream:
            self._stream_seen = time.monotonic()
            if self._state is State.SILENT:
                self._state = State.STREAMING  # (its timer gap was counted as lost_radio)
                self.stream_started = self._stream_seen
                self.trouble = None
        # anything but the next record of the stream a streaming node is known to stream
        # is for the supervisor to look at; saying so here, where it is known, saves the
        # reader a call for every record: 1.8% of the instructions a record takes
        # (valgrind --tool=callgrind on bench/ab.py's read path)
        self.unusual = not is_stream or self._state is not State.STREAMING or self.timer_reset
        return payload

    def _timer_restarted(self) -> None:
        """Its timer restarted: a reboot, counted here unless a discovery packet
        announced it (:meth:`rebooted` counted it then)."""
        if not self._reboot_announced:
            self.reboots += 1
            self.timer_reset = True
        self._reboot_announced = False
        # no gap across a power-up
        self._last_stream_device = self._down_from = self._back_at = None
        self.clock.reset()
        self._epoch = next(_EPOCHS)
        self._least_wait = math.inf

    def take_wait(self) -> Waited:
        """What its records since the last call say of a queue on its serial line
        (:mod:`.lineload`)."""
        wait, self._least_wait = self._least_wait, math.inf
        clock = self.clock
        if clock.floors_taken_back != self._floors_taken_back:
            self._floors_taken_back = clock.floors_taken_back
            self._epoch = next(_EPOCHS)
        return Waited(self.address, wait, self._epoch, clock.floor_seen,
                      clock.held_error() or 0.0)

    def _after_last_time(self, sampled: float) -> float:
        """``time`` for a record whose ``sampled`` is not above the last one published.
        The clock gives every record a later time than the one before, if only by a
        nanosecond (two records of one cycle); converted to UNIX seconds, near 1.7e9
        where a double's step is 238 ns, that nanosecond is lost, and the UNIX clock
        less the monotonic one, read one after the other at each read, moves by a
        fraction of a microsecond between reads: such a fall is moved to just above the
        last time. A fall of TIME_NOISE or more is the host's clock stepped back (NTP),
        and ``time`` moves by the step (docs/interface.md, Sample time), or a reboot's
        new line: the clock never gives a time below one it gave before except across a
        reset (:mod:`aspp.clockstate`), so nothing here is slewed back afterwards."""
        last = self._last_time
        return math.nextafter(last, math.inf) if last - sampled < TIME_NOISE else sampled

    def _count_gaps(self, device: float) -> None:
        """Samples lost over the air, from the device time (the timer unwrapped, so an
        outage of any length, wraps included, is counted whole): the stream's records
        are exactly one period apart, so a longer step is records that never arrived.

        Every STEPS_CHECKED steps the shortest one is compared with the divider: a
        stream that never once stepped by one period does not run at it."""
        last, self._last_stream_device = self._last_stream_device, device
        if last is None:
            if self._down_from is not None:  # the first record since the station was down
                self._count_station_down(device)
            return
        step = round((device - last) * CLOCK_HZ)  # in periods of the 51,200 Hz clock
        if step < self._shortest_step:
            self._shortest_step = step
        self._steps += 1
        if self._steps == STEPS_CHECKED:
            if self._shortest_step != self._divider and valid_divider(self._shortest_step):
                self.divider = self._shortest_step
            self._steps, self._shortest_step = 0, _NO_STEP
        missing = round(step / self._divider) - 1
        if missing > 0:
            self.lost_radio += missing

    def _count_station_down(self, device: float) -> None:
        """The samples missing between the stream's last record before its base station
        went down and ``device``, its first since: those that fell due before the station
        was back are ``lost_station_down``, any after it (a node that had gone out of
        range meanwhile) ``lost_radio``."""
        (before, seen), back = self._down_from, self._back_at  # type: ignore[misc]
        self._down_from = self._back_at = None
        missing = max(0, round((device - before) * CLOCK_HZ / self._divider) - 1)
        down = missing if back is None else min(missing, math.ceil((back - seen) / self.period))
        self.lost_station_down += down
        self.lost_radio += missing - down

    def _close_rate_window(self, now: float) -> None:
        elapsed = now - self._window_start
        self.rate_hz = self._window_count / elapsed if elapsed < 2 * RATE_WINDOW else 0.0
        self._window_start, self._window_count = now, 0

    def publish_failed(self) -> None:
        """Its last record was not published (ZeroMQ refused it)."""
        self.lost_gateway += 1

    # -- transitions --------------------------------------------------------------------

    def reconfigure(self, config: NodeEntry) -> bool:
        """A reload changed its entry: its name and gyro model from now on. True if its
        ``stream`` changed: that is what it should stream now, whatever an operator
        asked before (a ``stream`` taken out: stopped)."""
        streams = config.stream != self.config.stream
        self.config, self.name, self.label = config, config.name, config.label
        if streams:
            self.desired = OFF if config.stream is None else config.stream
        return streams

    def want(self, record: str | None) -> None:
        """The operator's intent: stream ``record``, or stay stopped (OFF)."""
        self.desired = record

    def arming(self) -> None:
        self._state = State.ARMING

    def unreachable(self) -> None:
        self._state = State.UNREACHABLE
        self.trouble = "unreachable"

    def streaming(self, record: str, divider: int | None = None) -> None:
        """The node now streams ``record`` (at ``divider``, if that is known)."""
        self.record = record
        if divider is not None and valid_divider(divider):
            self.divider = divider
        self._state = State.STREAMING
        self.trouble = None
        self._restart_stream()

    def polled(self) -> None:
        """The node streams nothing (as far as the gateway knows)."""
        self.record = None
        self._state = State.POLLED
        self.trouble = None
        self._down_from = None  # (a stream started later has no gap to count)
        self._restart_stream()

    def _restart_stream(self) -> None:
        self._last_stream_device = None
        self._steps, self._shortest_step = 0, _NO_STEP
        self._stream_seen = self.stream_started = time.monotonic()

    def settled(self) -> None:
        """Nothing to pursue: the node does what it is known to do."""
        if self.record:
            self.streaming(self.record)
        else:
            self.polled()

    def divider_read(self, divider: int) -> None:
        """The divider its EEPROM holds (ignored if it is not a valid one)."""
        if valid_divider(divider):
            self.divider = divider

    def stopping(self) -> None:
        self._state = State.STOPPING

    def busy(self) -> None:
        self._state = State.BUSY

    def stop_failed(self) -> None:
        """A stop gave up or was abandoned: the stream goes on (unless something else,
        the link lost, has happened to the node meanwhile)."""
        if self._state is State.STOPPING:
            self.settled()

    def rebooted(self) -> None:
        """A discovery packet: the node lost power; whatever it streamed is gone, and
        its timer starts again."""
        self.reboots += 1
        self.clock.reset()
        # its timer restarting is the same reboot: the unwrapper takes the next reading
        # that is not of the old power-up as the new one's, whatever its timer says
        self._reboot_announced = self._unwrapper.expect_reset()
        self.record = None
        self._state = State.REBOOTED
        self._last_stream_device = self._down_from = self._back_at = None

    def rebooted_quietly(self) -> None:
        """A reboot its timer showed (counted by :meth:`tally`): its stream is unknown."""
        self.record = None
        self._state = State.REBOOTED
        self._last_stream_device = None

    def take_timer_reset(self) -> bool:
        """Whether the timer showed an unannounced reboot since the last call."""
        reset, self.timer_reset = self.timer_reset, False
        return reset

    def link_lost(self) -> None:
        """The base station went away: what is missed now is not lost over the air.
        A node streams on while its base station is unplugged, so the stream's first
        record once it is back tells how many samples went by: ``lost_station_down``
        (a stream started afresh in between, as the supervisor does when the station
        returns, is the same stream on the same timer; a reboot meanwhile ends it)."""
        self._state = State.LINK_DOWN
        if self._last_stream_device is not None:
            self._down_from = (self._last_stream_device, self._stream_seen)
            self._back_at = None
        self._last_stream_device = None

    def link_back(self) -> None:
        """Its base station is back: samples missed from now on are the radio's."""
        if self._down_from is not None:
            self._back_at = time.monotonic()

    def silent_at(self) -> float | None:
        """When (``time.monotonic()``) the stream falls silent if no record comes first;
        None if there is no stream to watch."""
        if self._state is not State.STREAMING or self.record is None:
            return None
        return self._stream_seen + self.silence_limit

    def fell_silent(self, now: float) -> bool:
        """Whether the stream just fell silent (checked against ``time.monotonic()``);
        if so it is counted and the state says so."""
        due = self.silent_at()
        if due is None or now <= due:
            return False
        self.silences += 1
        self._state = State.SILENT  # (if the stream resumes, its timer gap is lost_radio)
        self.trouble = "silent"
        return True

    # -- status --------------------------------------------------------------------------

    def clock_status(self, now: float) -> dict[str, Any] | None:
        """The clock estimate on the UNIX clock at ``now`` (None before a timed record):
        ``offset`` is when its timer read 0 (its power-up), less the latency."""
        if self.clock.points == 0:
            return None
        estimate = self.clock.estimate()
        shift = now - time.monotonic()
        age, late = self.clock.floor_age, self.floor_unseen()
        return {"offset": estimate.offset - self._latency + shift,
                # how fast its timer runs against the host's clock (positive: fast)
                "drift_ppm": round((1 / (1 + estimate.drift) - 1) * 1e6, 3),
                "spread_ms": round(estimate.spread * 1e3, 4), "locked": estimate.locked,
                "since": None if estimate.locked_since is None
                else estimate.locked_since + shift,
                "floor_age_s": None if age is None else round(age, 2),
                "floor_seen": self.clock.floor_seen,
                "late_ms": None if late is None else round(late * 1e3, 3)}

    def floor_unseen(self) -> float | None:
        """How late ``time`` may be (seconds, :meth:`aspp.clock.NodeClock.late_bound`)
        while its clock has gone floor_unseen_s or longer without seeing its floor;
        None otherwise (seen since, or no lock to judge)."""
        age = self.clock.floor_age
        if age is None or age < self.floor_unseen_s or not self.clock.floor_seen:
            return None  # (never seen: no bound comes with the wait, aspp.clock.floor_seen)
        return self.clock.late_bound()

    def status(self, now: float) -> dict[str, Any]:
        if self.last_seen is not None and now - self.last_seen > 2 * RATE_WINDOW:
            self.rate_hz = 0.0
        return {"node": self.address, "name": self.name, "station": self.station,
                "state": str(self._state),
                "record": self.record, "configured": self.config.stream,
                "desired": self.desired, "rate_hz": round(self.rate_hz, 2),
                "divider": self.divider, "packets": self.packets, "published": self.seq,
                "lost_radio": self.lost_radio, "lost_station_down": self.lost_station_down,
                "lost_gateway": self.lost_gateway,
                "reboots": self.reboots, "silences": self.silences, "lqi": self.lqi,
                "rssi": self.rssi, "last_seen": self.last_seen, "seq": self.seq,
                "clock": self.clock_status(now)}
