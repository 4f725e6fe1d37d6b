"""What each control op does: one async function per row of the op table
(:mod:`gateway.common.ops`), registered under the row's name with :func:`handles`.

Single steps (a poll) and multi-step ones (write then verify) read top to bottom here;
the scheduler decides when each packet goes out, and the supervisor owns everything
about a node's stream (``start`` and ``stop`` change what it pursues).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections import Counter
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Sequence
from typing import Any, Protocol

from aspp import commands
from aspp.commands import DOCUMENTED_EEPROM, EEPROM_DIVIDER
from aspp.frame import encode_ping
from aspp.records import Record
from aspp.timing import data_rate, divider_for_rate
from gateway.common import ops

from .errors import Invalid, NodeError, OpError, Refused
from .requests import RequestBase, answer_within
from .station.nodes import Node
from .station.reader import Reader
from .station.scheduler import Scheduler
from .station.supervisor import Supervisor
from .stations import Stations


class StationParts(Protocol):
    """What the ops need of a base station (:class:`~.station.Station`)."""

    name: str
    nodes: dict[int, Node]
    reader: Reader
    scheduler: Scheduler
    supervisor: Supervisor
    replaying: bool

Result = dict[str, Any]
RELOAD_SHARE = 0.8
"""Of the time a reload request is answered within: how long it waits for operations
on the nodes it changes before answering that it waits (it goes on, and is logged)."""
Handler = Callable[["Operations", Any], Awaitable[Result]]
HANDLERS: dict[str, Handler] = {}


def handles(name: str) -> Callable[[Handler], Handler]:
    """Register the function that runs op ``name`` (a row of the op table)."""
    if name not in ops.BY_NAME:
        raise ValueError(f"{name!r} is not in the op table")

    def register(handler: Handler) -> Handler:
        HANDLERS[name] = handler
        return handler
    return register


class Operations:
    """What the handlers run against: the nodes, the scheduler, the supervisor and the
    gateway's policy."""

    def __init__(self, stations: Sequence[StationParts], status: Callable[[], Result], *,
                 allow_eeprom_write: bool, allow_any_eeprom_address: bool = False,
                 publish_mark: Callable[[Result], Awaitable[bool]] | None = None,
                 reload: Callable[[float | None], Awaitable[Result]] | None = None
                 ) -> None:
        self.stations = stations if isinstance(stations, Stations) else Stations(stations)
        """The one node -> station map is the gateway's (:mod:`.stations`), shared."""
        self.nodes = self.stations.nodes
        self.station_of = self.stations.of
        self.status = status
        self.allow_eeprom_write = allow_eeprom_write
        self.allow_any_eeprom_address = allow_any_eeprom_address
        self.replaying = self.stations.replaying
        """Playing a recording: nothing may be sent to a node."""
        self.publish_mark = publish_mark
        """Publishes a mark, and waits for the recording to keep it; False if it
        could not be published."""
        self.reload = reload
        """Reloads the configuration file (:class:`~.reload.Reloader`), answering
        within the seconds given; None: cannot."""
        self._tasks: set[asyncio.Task[None]] = set()
        self._running: Counter[int] = Counter()
        """Node address -> the requests naming it that are running."""
        self._waiting: list[asyncio.Event] = []
        self._reserved: dict[int, str] = {}
        """Node address -> what a pending reload does to it (``removing``): new
        requests naming it are refused, so the reload waits only for those running."""

    async def run(self, request: RequestBase) -> Result:
        op = request.op  # type: ignore[attr-defined]
        if self.replaying and ops.BY_NAME[op].talks_to_node:
            raise Refused(f"{op}: this gateway is replaying a recording and sends "
                          "nothing to any node")
        named = _named(request)
        for address in named:
            if address in self._reserved:
                raise Refused(f"{op}: a reload is {self._reserved[address]} node "
                              f"{address}; it waits for the operation already running "
                              "on it (the gateway's log says when it is applied)")
        self._running.update(named)
        try:
            return await HANDLERS[op](self, request)
        finally:
            for address in named:
                self._running[address] -= 1
                if not self._running[address]:
                    del self._running[address]
            for event in self._waiting:
                event.set()

    def busy(self, addresses: set[int]) -> set[int]:
        """Those of ``addresses`` a running request names."""
        return {address for address in addresses if self._running[address] > 0}

    @contextlib.contextmanager
    def reserved(self, doing: dict[int, str]) -> Iterator[None]:
        """While a reload is pending: a new request naming one of ``doing``'s nodes
        is refused, saying what the reload does to it."""
        self._reserved.update(doing)
        try:
            yield
        finally:
            for address in doing:
                self._reserved.pop(address, None)

    async def idle(self, addresses: set[int]) -> None:
        """Until no request naming one of ``addresses`` runs (a reload waits so for the
        nodes it changes; it never cancels an operation)."""
        while any(self._running[address] > 0 for address in addresses):
            event = asyncio.Event()
            self._waiting.append(event)
            try:
                await event.wait()
            finally:
                self._waiting.remove(event)

    def scheduler(self, node: Node) -> Scheduler:
        """The scheduler of the base station ``node`` is on."""
        return self.station_of[node.address].scheduler

    def supervisor(self, node: Node) -> Supervisor:
        """The supervisor of the base station ``node`` is on."""
        return self.station_of[node.address].supervisor

    def node(self, address: int) -> Node:
        state = self.nodes.get(address)
        if state is None:
            raise Invalid(f"node {address} is not configured in this gateway")
        return state

    def check_writes_allowed(self, what: str = "EEPROM writes") -> None:
        """Refused unless allow_eeprom_write: ``what`` changes what a node keeps."""
        if not self.allow_eeprom_write:
            raise Refused(f"{what} is disabled on this gateway (it changes what the node "
                          "measures or keeps); to allow it set "
                          "control.allow_eeprom_write: true in its configuration and "
                          "restart it")

    def spawn(self, coroutine: Coroutine[Any, Any, None]) -> None:
        """Work that outlives its request (switching a node's BIT off until it is)."""
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def close(self) -> None:
        for task in self._tasks:
            task.cancel()


@handles("status")
async def status(gw: Operations, request: Any) -> Result:
    return gw.status()


@handles("ping")
async def ping(gw: Operations, request: Any) -> Result:
    """Each node its own answer: a node whose base station is down is reported as such
    (``error``) beside the others' answers, never the whole request failed for it."""
    addresses = request.nodes
    # a configured node is pinged through its own base station, any other address
    # through the first (one wireless ping reaches only its station's channel)
    stations = [gw.station_of.get(a, gw.stations[0]) for a in addresses]
    results = await asyncio.gather(*(station.scheduler.ping(a, encode_ping(a))
                                     for station, a in zip(stations, addresses, strict=True)),
                                   return_exceptions=True)
    nodes = []
    for address, result in zip(addresses, results, strict=True):
        entry: Result = {"node": address, "answered": result is True}
        if isinstance(result, BaseException):
            if not isinstance(result, OpError):
                raise result  # a bug: the control server answers and logs it
            if not isinstance(result, NodeError):  # (no answer byte at all: not answered)
                entry["error"] = str(result)  # its base station is down
        nodes.append(entry)
    return {"nodes": nodes}


@handles("start")
async def start(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return await gw.supervisor(node).start(node, request.record)


@handles("stop")
async def stop(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return await gw.supervisor(node).stop(node)


@handles("poll")
async def poll(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    return (await gw.scheduler(node).ask(node, commands.poll(request.record))).payload


@handles("eeprom_read")
async def eeprom_read(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    value = (await gw.scheduler(node).ask(node, commands.read_eeprom(request.address))
             ).record["value"]
    return {"node": node.address, "address": request.address, "value": value}


@handles("eeprom_write")
async def eeprom_write(gw: Operations, request: Any) -> Result:
    return await write_word(gw, gw.node(request.node), request.address, request.value)


async def write_word(gw: Operations, node: Node, word: int, value: int) -> Result:
    """Write, retry once if the reply shows the old word (the reference: the first
    write after power-up may fail), then read it back."""
    gw.check_writes_allowed("writing EEPROM")
    if word not in DOCUMENTED_EEPROM and not gw.allow_any_eeprom_address:
        known = ", ".join(f"0x{a:04X} ({what})" for a, what in DOCUMENTED_EEPROM.items())
        raise Refused(f"EEPROM 0x{word:04X} is not a word the reference documents "
                      f"({known}); to write it anyway set "
                      "control.allow_any_eeprom_address: true and restart the gateway")
    attempts = 0
    while True:
        attempts += 1
        stored = (await gw.scheduler(node).ask(node, commands.write_eeprom(word, value))
                  ).record["value"]
        if stored == value:
            break
        if attempts == 2:
            raise NodeError(f"node {node.address}: EEPROM 0x{word:04X} still holds "
                            f"{stored} after 2 writes of {value}")
    readback = (await gw.scheduler(node).ask(node, commands.read_eeprom(word))).record["value"]
    if readback != value:
        raise NodeError(f"node {node.address}: EEPROM 0x{word:04X} reads back "
                        f"{readback}, not {value}")
    if word == EEPROM_DIVIDER:
        node.divider_read(value)
    return {"node": node.address, "address": word, "value": value, "attempts": attempts}


@handles("rate")
async def rate(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)
    divider = divider_for_rate(request.hz)  # (the request model checked it)
    await write_word(gw, node, EEPROM_DIVIDER, divider)
    return {"node": node.address, "hz": round(data_rate(divider), 3), "divider": divider}


@handles("info")
async def info(gw: Operations, request: Any) -> Result:
    node = gw.node(request.node)

    async def ask(command: commands.Command) -> Record:
        return (await gw.scheduler(node).ask(node, command)).record
    return {"node": node.address, **await identify(node.address, ask)}


IDENTITY = ("model_number", "serial_number", "model_name", "options")
"""The four identifier strings (0xEA), by selector."""


async def identify(address: int, ask: Callable[[commands.Command], Awaitable[Record]]
                   ) -> Result:
    """What a node is: its firmware version and four identifier strings, each read with
    ``ask`` (a command to the node, its reply's record)."""
    result: Result = {}
    for _, command, fields in identity_reads(address):
        result.update(fields(await ask(command)))
    return result


def identity_reads(address: int) -> list[tuple[str, commands.Command,
                                               Callable[[Record], Result]]]:
    """The reads :func:`identify` makes, one at a time: the field each fills, its
    command, and the fields its reply's record gives (a scan cut short goes on from
    the first read it lacks)."""
    def version(record: Record) -> Result:
        return {"firmware": record["version"],
                "firmware_version": commands.firmware_text(record["version"])}

    def text(selector: int) -> Callable[[Record], Result]:
        def field(record: Record) -> Result:
            if record["selector"] != selector:  # a late answer to an earlier request
                raise NodeError(f"node {address}: asked for identifier {selector}, "
                                f"got {record['selector']}")
            return {IDENTITY[selector]: record["text"]}
        return field
    return [("firmware", commands.firmware_version(), version),
            *((key, commands.device_id(selector), text(selector))
              for selector, key in enumerate(IDENTITY))]


def _named(request: Any) -> list[int]:
    """The node addresses a request names."""
    node = getattr(request, "node", None)
    return [*(() if node is None else (node,)), *getattr(request, "nodes", ())]


@handles("reload")
async def reload(gw: Operations, request: Any) -> Result:
    """As SIGHUP: the nodes of the configuration file applied, or the reload refused
    whole (Invalid: the file does not check; Refused: it needs a restart)."""
    if gw.reload is None:
        raise Refused("reload: this gateway was not started from a configuration file")
    return await gw.reload(None if request.timeout is None
                           else RELOAD_SHARE * answer_within(request.timeout))


@handles("mark")
async def mark(gw: Operations, request: Any) -> Result:
    """The moment the gateway took it, on its clock: the one every record's ``time`` and
    ``host_time`` are on, so a mark lines up with the samples around it."""
    if gw.replaying:
        raise Refused("mark: this gateway is replaying a recording; a mark belongs to "
                      "what is happening now, on a live gateway")
    nodes = [gw.node(address).address for address in request.nodes]
    now = time.time()
    payload = {"text": request.text, "time": now, "host_time": now, "nodes": nodes}
    if gw.publish_mark is None or not await gw.publish_mark(payload):
        raise OpError("the mark could not be published (the gateway's log says why)")
    return dict(payload)


# the ops that measure, correct and check what a node senses, and the scan, register
# themselves there
from . import calibration, scanning  # noqa: E402, F401
