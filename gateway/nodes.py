"""Per-node state: what each configured node is doing, and the payload of every record
it sends (seq, device time, link quality), built here once per record.

This is on the per-record path: plain attributes and dicts, no pydantic, no copies.
"""

from __future__ import annotations

import time
from typing import Any, NamedTuple

from aspp.events import LINK_QUALITY, Reply
from aspp.records import Record
from aspp.stop import StopPolicy
from aspp.timing import TICKS_PER_SECOND, TIMER_MODULUS, TimerUnwrapper

from .config import NodeConfig

DEFAULT_DIVIDER = 512
RATE_WINDOW = 2.0
"""Seconds over which the record rate is measured."""
SILENCE_MIN = 1.0
SILENCE_PERIODS = 10
"""A stream with no record for this many sample periods (and at least SILENCE_MIN
seconds) has fallen silent: the node rebooted with its discovery packet lost, or went
out of range."""


class Delivery(NamedTuple):
    """A reply as the operations see it: the decoded record and its published payload
    (made for every record: a NamedTuple is the cheapest immutable pair)."""

    record: Record
    payload: dict[str, Any]


class NodeState:
    """One configured node."""

    def __init__(self, config: NodeConfig) -> None:
        self.config = config
        self.address = config.address
        self.name = config.name
        self.state = "unknown"
        self.record: str | None = None
        """The record it streams, as far as the gateway knows."""
        self.divider = DEFAULT_DIVIDER
        self.seq = 0
        self.packets = 0
        self.lost_radio = 0
        self.lost_gateway = 0
        self.reboots = 0
        self.silences = 0
        self.quiet_reboot = False
        """A reboot seen only in the timer, while something other than the configured
        stream was coming: the daemon re-arms the node."""
        self.lqi: int | None = None
        self.rssi: int | None = None
        self.last_seen: float | None = None
        self.rate_hz = 0.0
        self.stop_policy: StopPolicy | None = None
        self._unwrapper = TimerUnwrapper()
        self._reboot_announced = False
        self._last_stream_timer: int | None = None
        self._stream_seen = 0.0
        """time.monotonic() of the last record of the stream (or of its start)."""
        self._window_start = 0.0
        self._window_count = 0

    @property
    def period(self) -> float:
        return self.divider / 51200

    @property
    def silence_limit(self) -> float:
        return max(SILENCE_MIN, SILENCE_PERIODS * self.period)

    def payload(self, event: Reply, record: Record, host_time: float) -> dict[str, Any]:
        """Count the record and build its published payload (CONTRACT section 4)."""
        self.seq = seq = self.seq + 1
        self.packets += 1
        raw = event.raw
        self.lqi, self.rssi = lqi, rssi = LINK_QUALITY.unpack_from(raw, len(raw) - 4)
        self.last_seen = host_time
        self._window_count += 1  # the record rate, measured over RATE_WINDOW
        if host_time - self._window_start >= RATE_WINDOW:
            self._close_rate_window(host_time)
        spec = record.spec
        name = spec.name
        # the fields, then the rest, in one call: dict() sets keyword arguments in C,
        # where item by item each costs a Python step (and zip without strict=: the
        # keyword alone costs a third more; decode() made the lengths equal)
        payload = dict(zip(spec.field_names, record.values),  # noqa: B905
                       node=self.address, record=name, command=spec.code, seq=seq,
                       host_time=host_time, lqi=lqi, rssi=rssi)
        is_stream = name == self.record
        timer = payload.get("timer")
        if timer is not None:
            unwrapper = self._unwrapper
            payload["device_time"] = unwrapper.update(timer, host_time)
            if unwrapper.last_was_reset:
                if not self._reboot_announced:  # a reboot seen only in the timer
                    self.reboots += 1
                    self.quiet_reboot = name != self.config.stream
                self._reboot_announced = False
                self._last_stream_timer = None  # no gap across a power-up
            if is_stream:
                self._count_gaps(timer)
        if is_stream:
            self._stream_seen = time.monotonic()
            if self.state == "silent":
                self.state = "streaming"
        if self.stop_policy is not None and spec.streamable:
            self.stop_policy.packet_seen(time.monotonic())
        return payload

    def _count_gaps(self, timer: int) -> None:
        """Samples lost over the air, from the device timer: the stream's records are
        exactly one period apart, so a longer step is records that never arrived."""
        last, self._last_stream_timer = self._last_stream_timer, timer
        if last is None:
            return
        step = self.divider * (TICKS_PER_SECOND // 51200)
        missing = round(((timer - last) % TIMER_MODULUS) / step) - 1
        if 0 < missing < 10_000:
            self.lost_radio += missing

    def _close_rate_window(self, now: float) -> None:
        elapsed = now - self._window_start
        self.rate_hz = self._window_count / elapsed if elapsed < 2 * RATE_WINDOW else 0.0
        self._window_start, self._window_count = now, 0

    def streaming(self, record: str | None) -> None:
        """The node now streams ``record`` (None: polled mode)."""
        self.record = record
        self.state = "streaming" if record else "polled"
        self._last_stream_timer = None
        self._stream_seen = time.monotonic()

    def silent_at(self) -> float | None:
        """When (``time.monotonic()``) the stream falls silent if no record comes first;
        None if there is no stream to watch (or a stop of it is under way)."""
        if self.state != "streaming" or self.record is None or self.stop_policy is not None:
            return None
        return self._stream_seen + self.silence_limit

    def fell_silent(self, now: float) -> bool:
        """Whether the stream just fell silent (checked against ``time.monotonic()``);
        if so it is counted and the state says so."""
        due = self.silent_at()
        if due is None or now <= due:
            return False
        self.silences += 1
        self.state = "silent"  # (if the stream resumes, its timer gap is lost_radio)
        return True

    def rebooted(self) -> None:
        """A discovery packet: the node lost power; whatever it streamed is gone."""
        self.reboots += 1
        self._reboot_announced = True  # its timer going back is the same reboot
        self.record = None
        self.state = "rebooted"
        self._last_stream_timer = None

    def link_lost(self) -> None:
        """The base station went away: what is missed now is not lost over the air."""
        self.state = "link down"
        self._last_stream_timer = None

    def status(self, now: float) -> dict[str, Any]:
        if self.last_seen is not None and now - self.last_seen > 2 * RATE_WINDOW:
            self.rate_hz = 0.0
        return {"node": self.address, "name": self.name, "state": self.state,
                "record": self.record, "rate_hz": round(self.rate_hz, 2),
                "divider": self.divider, "packets": self.packets, "published": self.seq,
                "lost_radio": self.lost_radio, "lost_gateway": self.lost_gateway,
                "reboots": self.reboots, "silences": self.silences, "lqi": self.lqi,
                "rssi": self.rssi,
                "last_seen": self.last_seen, "seq": self.seq}
