"""What the control ops run against (:class:`Operations`: the nodes, their stations'
schedulers and supervisors, the gateway's policy) and the table of their functions,
each registered under its op's name with :func:`handles`. The functions are in
:mod:`.nodeops`, :mod:`.calibration` and :mod:`.scanning`, which import this module;
:mod:`.operations` imports them all, so that the table is whole (and this module
imports none of them: no import loop).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import Counter
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Sequence
from typing import Any, Protocol

from gateway.common import ops

from .errors import Invalid, Refused
from .requests import RequestBase
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


def _named(request: Any) -> list[int]:
    """The node addresses a request names."""
    node = getattr(request, "node", None)
    return [*(() if node is None else (node,)), *getattr(request, "nodes", ())]
