"""Who else is on the channel: the addresses a base station hears that it is not
configured for, remembered so that status can say who they are.

A node powered up near the base station announces itself with a discovery packet; a
node left streaming by another gateway (or before the configuration changed) keeps
sending its record; a node answers a command sent to it. Every such packet from an
address that is not configured is handed here by the reader (and was only counted,
``unknown_node_packets``, before): what the address sent (a discovery, which record),
the rate it streams at (from its timer's steps, as a configured node's divider is
checked), its LQI and RSSI (the median of its last few packets), when it was first and
last heard, and how many packets came from it.

Only packets of unconfigured addresses come here: a configured node's record never
does, so the per-record path pays nothing for it (bench/instructions.py). The memory is
bounded: at most :data:`HEARD_MAX` addresses a station, the one heard longest ago
forgotten first, so a channel full of strangers (or a false packet that passed its
checksum) costs a fixed amount.
"""

from __future__ import annotations

import logging
import statistics
import time
from collections import OrderedDict, deque
from typing import Any

from aspp.events import LINK_QUALITY
from aspp.frame import HEADER_SIZE
from aspp.records import BY_CODE, STREAMABLE
from aspp.timing import (
    TICKS_PER_CLOCK,
    TIMER_MODULUS,
    data_rate,
    sample_period,
    valid_divider,
)

from .nodes import SILENCE_MIN, SILENCE_PERIODS

log = logging.getLogger("gx2.heard")

HEARD_MAX = 256
"""Addresses remembered per base station; past it, the one heard longest ago is
forgotten. A few hundred: more nodes than one channel carries streaming (a 115200-baud
line fills with about ten at 100 Hz), and room for a box of silent ones announcing
themselves, while a status listing them all stays some tens of kB."""
LINK_SAMPLES = 9
"""Packets whose LQI and RSSI give the median shown: a few, so one packet caught in a
fade does not move it, and a node carried away shows it within seconds."""
LOG_BURST = 10
"""Addresses logged (each once, its first news) per LOG_WINDOW; past it, a count."""
LOG_WINDOW = 60.0
"""Seconds over which LOG_BURST counts; the next news after it logs the count of those
not logged."""
STREAM_RECORDS = 3
"""Records of one streamable kind in a row from an address before it is taken to
stream (two commands answered with the same record are not a stream)."""


def _median(values: deque[int]) -> float | None:
    return round(statistics.median(values), 1) if values else None


class HeardNode:
    """One address heard: what it sent, how well, and when."""

    def __init__(self, address: int, host_time: float) -> None:
        self.address = address
        self.packets = 0
        self.first_heard = host_time
        """UNIX seconds of its first packet (as status's other times)."""
        self.last_heard = host_time
        self.announced: float | None = None
        """UNIX seconds of its last discovery packet (its last power-up), if one came."""
        self.discoveries = 0
        self.record: str | None = None
        """The record it last sent since its last power-up (``0xNN`` for one this
        version does not know); None before any."""
        self._at = 0.0
        """time.monotonic() of its last packet: how long ago is judged on it."""
        self._gap = 0.0
        """Seconds between its last packet and the one before."""
        self._code: int | None = None
        """The command byte of the run of records it is sending."""
        self._run = 0
        """Records of that byte in a row."""
        self._run_from = 0.0
        """time.monotonic() of the run's first record."""
        self._timer: int | None = None
        """The timer of the run's last record (a timed one)."""
        self._step = 0
        """The shortest step of its timer within the run, in ticks (0: none yet): one
        sample period, whatever was lost over the air in between."""
        self._lqi: deque[int] = deque(maxlen=LINK_SAMPLES)
        self._rssi: deque[int] = deque(maxlen=LINK_SAMPLES)

    def heard(self, raw: bytes, host_time: float) -> None:
        """A packet of its, of either kind, read at ``host_time``: counted, with its
        link quality. How long ago it was is judged on time.monotonic() when it is
        handled (a replay's packets carry the recording's times)."""
        self.packets += 1
        now = time.monotonic()
        self._gap = now - self._at
        self.last_heard, self._at = host_time, now
        lqi, rssi = LINK_QUALITY.unpack_from(raw, len(raw) - 4)
        self._lqi.append(lqi)
        self._rssi.append(rssi)

    def reply(self, raw: bytes) -> bool:
        """A reply record: which one, and its timer's step if it continues a run.
        Whether the address has just begun to stream."""
        code = raw[HEADER_SIZE]
        spec = BY_CODE.get(code)
        self.record = spec.name if spec is not None else f"0x{code:02X}"
        if code != self._code or self._gap > self._silence():  # (a new run)
            self._code, self._run, self._run_from = code, 0, self._at
            self._timer, self._step = None, 0
        self._run += 1
        # the timer is a timed record's last field: the four bytes before LQI and RSSI
        if spec is not None and spec.timed and len(raw) - HEADER_SIZE - 4 == spec.reply_size:
            timer = int.from_bytes(raw[-8:-4], "big")
            if self._timer is not None:
                step = (timer - self._timer) % TIMER_MODULUS
                if valid_divider(round(step / TICKS_PER_CLOCK)) and (
                        not self._step or step < self._step):
                    self._step = step
            self._timer = timer
        return self._run == STREAM_RECORDS and code in STREAMABLE

    def discovery(self, host_time: float) -> None:
        """It powered up: whatever it streamed before is gone."""
        self.announced = host_time
        self.discoveries += 1
        self.record = None
        self._code, self._run, self._timer, self._step = None, 0, None, 0

    def rate_hz(self, monotonic: float) -> float | None:
        """The rate it streams its record at: from its timer's shortest step (the
        divider), else from the run's arrivals; None while it does not stream (fewer
        than STREAM_RECORDS of it in a row, not a streamable record, or none for as
        long as a configured node's stream takes to fall silent)."""
        if (self._run < STREAM_RECORDS or self._code not in STREAMABLE
                or monotonic - self._at > self._silence()):
            return None
        divider = round(self._step / TICKS_PER_CLOCK)
        if valid_divider(divider):
            return data_rate(divider)
        period = self._period()
        return None if period is None else 1 / period

    def _period(self) -> float | None:
        """Its stream's sample period: from its timer's shortest step, else from the
        run's arrivals; None before either can tell."""
        divider = round(self._step / TICKS_PER_CLOCK)
        if valid_divider(divider):
            return sample_period(divider)
        span = self._at - self._run_from
        return span / (self._run - 1) if span > 0 and self._run > 1 else None

    def _silence(self) -> float:
        """Seconds without a record after which its stream has stopped: as a configured
        node's falls silent (ten periods, and at least SILENCE_MIN)."""
        period = self._period()
        return SILENCE_MIN if period is None else max(SILENCE_MIN, SILENCE_PERIODS * period)

    def status(self, monotonic: float) -> dict[str, Any]:
        rate = self.rate_hz(monotonic)
        return {"address": self.address, "record": self.record,
                "rate_hz": None if rate is None else round(rate, 2),
                "rssi": _median(self._rssi), "lqi": _median(self._lqi),
                "packets": self.packets, "last_heard": self.last_heard,
                "first_heard": self.first_heard, "announced": self.announced,
                "discoveries": self.discoveries}


class Heard:
    """The unconfigured addresses one base station has heard, the most recently
    heard last; at most ``limit``."""

    def __init__(self, station: str = "", limit: int = HEARD_MAX) -> None:
        self.station = station
        self.limit = limit
        self.forgotten = 0
        """Addresses forgotten to keep within the limit."""
        self._nodes: OrderedDict[int, HeardNode] = OrderedDict()
        self._logged: set[int] = set()
        """Addresses whose news was logged (or counted) while they are remembered."""
        self._window = -LOG_WINDOW
        self._said = 0
        self._unsaid = 0

    def __len__(self) -> int:
        return len(self._nodes)

    def __contains__(self, address: object) -> bool:
        return address in self._nodes

    def _node(self, raw: bytes, host_time: float) -> HeardNode:
        """The packet's address, remembered (and made the most recent), its packet
        counted."""
        address = (raw[3] << 8) | raw[4]
        nodes = self._nodes
        node = nodes.get(address)
        if node is None:
            node = nodes[address] = HeardNode(address, host_time)
            if len(nodes) > self.limit:
                gone, _ = nodes.popitem(last=False)
                self._logged.discard(gone)
                self.forgotten += 1
        else:
            nodes.move_to_end(address)
        node.heard(raw, host_time)
        return node

    def reply(self, raw: bytes, host_time: float) -> None:
        """A reply packet (``raw``, whole) from an address not configured, read at
        ``host_time`` (UNIX seconds)."""
        node = self._node(raw, host_time)
        if node.reply(raw):
            self._say(node.address, "streams %s on its channel", node.record)

    def discovery(self, raw: bytes, host_time: float) -> None:
        """A discovery packet (a power-up) from an address not configured."""
        node = self._node(raw, host_time)
        node.discovery(host_time)
        self._say(node.address, "powered up")

    def _say(self, address: int, what: str, *args: object) -> None:
        """Log an address's first news once while it is remembered, and at most
        LOG_BURST addresses a LOG_WINDOW: a channel full of strangers (or a scan
        reading one that streams) cannot flood the log; gx2ctl status lists them all."""
        if address in self._logged:
            return
        self._logged.add(address)
        now = time.monotonic()
        if now - self._window >= LOG_WINDOW:
            if self._unsaid:
                log.info("base station %s: %d more addresses not configured heard in "
                         "%.0f s, not logged one by one (gx2ctl status lists them)",
                         self.station, self._unsaid, LOG_WINDOW)
            self._window, self._said, self._unsaid = now, 0, 0
        if self._said >= LOG_BURST:
            self._unsaid += 1
            return
        self._said += 1
        log.info("base station %s: node %d, not configured, " + what, self.station,
                 address, *args)

    def forget(self, address: int) -> None:
        """``address`` is configured now (a reload added it): it is no longer one heard
        that is not."""
        self._nodes.pop(address, None)
        self._logged.discard(address)

    def streaming(self, monotonic: float) -> list[tuple[HeardNode, float]]:
        """The addresses that stream now, with their rates, by address."""
        rated = ((node, node.rate_hz(monotonic)) for node in self._nodes.values())
        return sorted(((node, rate) for node, rate in rated if rate is not None),
                      key=lambda pair: pair[0].address)

    def status(self, monotonic: float) -> list[dict[str, Any]]:
        """What status lists (``heard``), by address."""
        return [self._nodes[address].status(monotonic) for address in sorted(self._nodes)]
