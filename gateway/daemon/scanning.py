"""The scan: which addresses answer on a base station's channel, and what each node is.

Address after address is pinged through the station's scheduler at operator priority,
as ``gx2ctl ping`` is, one ping at a time: when one is answered the scheduler first
sends whatever else waits (an operator's command, the supervisor arming a configured
node), then the scan's next ping, so the scan takes turns with the configured nodes'
commands and their streams go on. A ping is three bytes that the base station answers
itself: an absent address costs what the base station waits for it (30 ms on gx2-sim).

A node that answers is read, never written: its divider (EEPROM 0xFCA2, its rate),
firmware version, four identifier strings, and auto-start word (EEPROM 0xFCA6, what it
streams from power-up); what it streams now is the record it streams meanwhile (for a
configured node, what the gateway knows). LQI and RSSI come from its replies: a ping's
answer is one byte from the base station, without them. A node that stops answering
is left with what was read.

The control protocol answers a request once, so a request cannot report progress: a
request scans a batch of addresses and gx2ctl sends batch after batch, showing its
progress between them and stopping on Ctrl-C. A request scans what fits in the time
its client waits and says how many of its addresses that was (``scanned``); gx2ctl
sends the rest again.
"""

from __future__ import annotations

import asyncio
import contextlib
import statistics
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any
from weakref import WeakKeyDictionary

from aspp import Reply, commands
from aspp.commands import EEPROM_AUTO_START, EEPROM_DIVIDER
from aspp.frame import encode_ping
from aspp.records import STREAMABLE, Record
from aspp.timing import DEFAULT_DIVIDER, data_rate, sample_period, valid_divider

from .errors import Invalid, LinkDown, NodeError
from .nodeops import identity_reads
from .opcontext import Operations, Result, StationParts, handles
from .requests import answer_within
from .station.nodes import Delivery, State
from .station.scheduler import Scheduler

READ_SECONDS = 1.0
"""A request starts on another address only with this long left before it must be
answered: the time to read a node found at 100 Hz (7 reads, about 0.1 s on gx2-sim)
with room to spare. What is left over goes to the next request; so does a node whose
reads the time cut short (on a full line reading a node takes 3 to 4 s): the next
request goes on with the reads it lacks."""


@dataclass
class Stranger:
    """An address not configured here, as the scheduler addresses it."""

    address: int
    divider: int = DEFAULT_DIVIDER

    @property
    def period(self) -> float:
        return sample_period(self.divider)


@dataclass
class Heard:
    """What a node sent while the scan read it: the link quality of each packet, and
    the records it streamed."""

    links: list[tuple[int, int]] = field(default_factory=list)
    streamed: Counter[str] = field(default_factory=Counter)

    def link(self) -> dict[str, int | None]:
        if not self.links:
            return {"lqi": None, "rssi": None}
        return {"lqi": statistics.median_low(q for q, _ in self.links),
                "rssi": statistics.median_low(r for _, r in self.links)}


@handles("scan")
async def scan(gw: Operations, request: Any) -> Result:
    """Scan ``request.addresses`` on the named base station, or on every one at once
    (each its own channel); ``scanned``: how many of them (in ascending order) were
    scanned on every one (0: the first node's reads go on in the next request),
    ``found``: the nodes that answered among those."""
    stations = _stations(gw, request.station)
    for station in stations:
        if not station.scheduler.link_up:
            others = [s.name for s in stations if s is not station]
            hint = (f"; scan another with gx2ctl scan {others[0]}" if others
                    and request.station is None else "")
            raise LinkDown(f"base station {station.name} is down (not connected): "
                           f"nothing scanned{hint}")
    loop = asyncio.get_running_loop()
    until = (None if request.timeout is None
             else loop.time() + answer_within(request.timeout) - READ_SECONDS / 4)
    addresses = request.addresses
    tasks = [asyncio.ensure_future(_scan_station(station, addresses, until))
             for station in stations]
    try:
        done = await asyncio.gather(*tasks)
    finally:
        for task in tasks:
            task.cancel()
    scanned = min(count for _, count in done)
    if scanned == 0 and not any(addresses[0] in _begun.get(s.scheduler, {})
                                for s in stations):  # (else: reads to go on with)
        raise NodeError(f"no answer to a ping of {addresses[0]} within the request's "
                        f"{request.timeout:g} s (gx2ctl status shows the base station)")
    covered = set(addresses[:scanned])
    found = [entry for entries, _ in done for entry in entries if entry["address"] in covered]
    found.sort(key=lambda entry: entry["address"])
    return {"found": found, "scanned": scanned, "stations": [s.name for s in stations]}


def _stations(gw: Operations, name: str | None) -> list[StationParts]:
    if name is None:
        return list(gw.stations)
    for station in gw.stations:
        if station.name == name:
            return [station]
    raise Invalid(f"no base station is named {name!r} (this gateway has "
                  f"{', '.join(s.name for s in gw.stations)})")


async def _scan_station(station: StationParts, addresses: tuple[int, ...],
                        until: float | None) -> tuple[list[Result], int]:
    """Ping each address in turn, reading each node that answers, until the addresses
    or the time run out: (the nodes found, how many addresses were scanned). A node
    whose reads the time cut short is left for the next request, which goes on with
    the reads it lacks, unless this request got none of them answered (a node that
    answers pings only: it is reported as far as it answered)."""
    loop = asyncio.get_running_loop()
    found: list[Result] = []
    for index, address in enumerate(addresses):
        if index and until is not None and until - loop.time() < READ_SECONDS:
            return found, index
        try:
            async with asyncio.timeout_at(until):
                answered = await station.scheduler.ping(address, encode_ping(address))
        except TimeoutError:
            return found, index
        if answered:
            entry, resumable = await _read(station, address, until)
            if entry["unanswered"] == OUT_OF_TIME and (index or resumable):
                return found, index  # (the next request goes on reading it)
            _begun.get(station.scheduler, {}).pop(address, None)
            found.append(entry)
    return found, len(addresses)


OUT_OF_TIME = "out of time before every read was answered"
RESUME_SECONDS = 60.0
"""How long what was read of a node waits for the next request to go on with it."""
FRUITLESS = 5
"""Requests in a row that got none of a node's reads answered before it is reported
as far as it answered (it answers pings only, say). A node answers a command after its
own record of the cycle (the reference), so on a full line its reply meets the base
station's buffer at one phase against the other nodes' records, full or not, until
their crystals drift it elsewhere: on gx2-sim's line with five nodes at 100 Hz one
read went unanswered through two whole requests in a row here, and three in CI (3 was
the count then, and the node was reported half read). The cost: a node that answers
pings but no read, on a line so full that its four attempts outlast a request, holds
the scan for five requests (about 22 s at gx2ctl's 4.5 s) before it is reported; on a
free line its attempts end within the first request, and it is reported then."""


@dataclass
class Begun:
    """A node whose reads a request's time cut short."""

    when: float
    entry: Result
    heard: Heard
    fruitless: int = 0
    """Requests in a row that got none of its reads answered."""


_begun: WeakKeyDictionary[Scheduler, dict[int, Begun]] = WeakKeyDictionary()
"""Per base station (its scheduler), the nodes whose reads go on in the next request."""


async def _read(station: StationParts, address: int, until: float | None
                ) -> tuple[Result, bool]:
    """What the node at ``address`` is, from the reads it answers before ``until``
    (going on from where the last request's time cut them short), and whether the
    next request should go on with them (cut short, and not FRUITLESS)."""
    node = station.nodes.get(address)
    loop = asyncio.get_running_loop()
    begun = _begun.setdefault(station.scheduler, {})
    for stale in [a for a, b in begun.items() if loop.time() - b.when > RESUME_SECONDS]:
        del begun[stale]
    earlier = begun.pop(address, None)
    entry, heard = (earlier.entry, earlier.heard) if earlier is not None else ({
        "address": address, "station": station.name, "lqi": None, "rssi": None,
        "firmware": None, "firmware_version": None, "model_number": None,
        "serial_number": None, "model_name": None, "options": None, "divider": None,
        "rate_hz": None, "auto_start": None, "streaming": None, "unanswered": None},
        Heard())
    entry.update(configured=node is not None, name=node.name if node is not None else None,
                 unanswered=None)
    addressee = node if node is not None else Stranger(address)
    reads = _Reads(station.scheduler, addressee, heard)
    progressed = False
    try:
        with _listening(station, address, heard):
            async with asyncio.timeout_at(until):
                if entry["divider"] is None:
                    divider = (await reads.ask(commands.read_eeprom(EEPROM_DIVIDER))
                               )["value"]
                    entry["divider"] = divider
                    if valid_divider(divider):
                        entry["rate_hz"] = round(data_rate(divider), 3)
                    progressed = True
                if isinstance(addressee, Stranger) and valid_divider(entry["divider"]):
                    addressee.divider = entry["divider"]
                for key, command, fields in identity_reads(address):
                    if entry[key] is None:
                        entry.update(fields(await reads.ask(command)))
                        progressed = True
                word = (await reads.ask(commands.read_eeprom(EEPROM_AUTO_START)))["value"]
                entry["auto_start"] = commands.auto_start_record(word)
    except TimeoutError:
        entry["unanswered"] = OUT_OF_TIME
        fruitless = 0 if progressed else 1 + (earlier.fruitless if earlier else 0)
        begun[address] = Begun(loop.time(), entry, heard, fruitless)
    except NodeError as error:  # (a base station gone, LinkDown, ends the scan)
        entry["unanswered"] = str(error)
    entry.update(heard.link())
    if node is not None:
        entry["streaming"] = node.record if node.state is State.STREAMING else None
        if entry["lqi"] is None and node.lqi is not None:
            entry.update(lqi=node.lqi, rssi=node.rssi)
    elif heard.streamed:
        entry["streaming"] = heard.streamed.most_common(1)[0][0]
    later = begun.get(address)
    return dict(entry), later is not None and later.fruitless < FRUITLESS


class _Reads:
    """A scan's reads of one node: each answer's link quality kept."""

    def __init__(self, scheduler: Scheduler, addressee: Any, heard: Heard) -> None:
        self.scheduler = scheduler
        self.addressee = addressee
        self.heard = heard

    async def ask(self, command: commands.Command) -> Record:
        delivery = await self.scheduler.ask(self.addressee, command)
        payload = delivery.payload
        if isinstance(payload.get("lqi"), int) and isinstance(payload.get("rssi"), int):
            self.heard.links.append((payload["lqi"], payload["rssi"]))
        return delivery.record


@contextlib.contextmanager
def _listening(station: StationParts, address: int, heard: Heard) -> Iterator[None]:
    """While a node not configured here is read, its records reach the scan: the
    replies to the reads (handed to the scheduler, which waits for them) and its
    stream's. A configured node's come the usual way."""
    if address in station.nodes:
        yield
        return
    scheduler = station.scheduler

    def listen(event: Reply, record: Record) -> None:
        code = record.spec.code
        if scheduler.expects(address, code):
            scheduler.on_reply(address, code, Delivery(record, {
                "node": address, "record": record.spec.name, "lqi": event.lqi,
                "rssi": event.rssi}))
        elif code in STREAMABLE:
            heard.links.append((event.lqi, event.rssi))
            heard.streamed[record.spec.name] += 1

    station.reader.listeners[address] = listen
    try:
        yield
    finally:
        station.reader.listeners.pop(address, None)
