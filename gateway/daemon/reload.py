"""Reloading the configuration while the gateway runs (SIGHUP, ``gx2ctl reload``).

Only the node lists change live: nodes added, removed or changed on a base station
that is already running. Everything else (endpoints, stations and their ports, the
recording, metrics, live view, health, curve, control's policy) is read once, at
start: a reload that changes any of it is refused whole, naming the first key that
differs, and nothing is applied. All or nothing, so the running configuration is
always one the file held.

:func:`plan` compares the running configuration with the file's, and says what a
reload would do; :class:`Reloader` applies it to the running stations without
touching any other node (docs/operating.md, "Reloading the configuration (nodes
added and removed)").
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .config import ConfigError, GatewayConfig, NodeEntry, StationConfig, load_config
from .errors import Invalid, Refused
from .station.ports import SIM_SCHEME
from .station.replayurl import SCHEME as REPLAY_SCHEME

if TYPE_CHECKING:
    from .health import Health
    from .operations import Operations
    from .station.station import Station
    from .stations import Stations

log = logging.getLogger("gx2.gateway")
KEPT = "the running configuration is kept"
"""What every refusal ends with: nothing of the file was applied."""
NODE_KEYS = ("base_station", "base_stations", "nodes")
"""The keys whose nodes may change live (the stations under them may not)."""


READ_SECONDS = 5.0
"""How long reading the file may take (a FIFO, a stalled network file system) before
the reload is refused; the gateway goes on meanwhile."""


class NeedsRestart(Exception):
    """The file changes what cannot change while the gateway runs (one line)."""


@dataclass(frozen=True)
class Plan:
    """What a reload does: nodes by (station name, entry or address)."""

    added: tuple[tuple[str, NodeEntry], ...] = ()
    removed: tuple[tuple[str, int], ...] = ()
    changed: tuple[tuple[str, NodeEntry], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.added or self.removed or self.changed)

    @property
    def touched(self) -> set[int]:
        """The running nodes it changes (an operation on one is waited for)."""
        return set(self.doing)

    @property
    def doing(self) -> dict[int, str]:
        """Each running node it changes, and how (``removing``, ``changing``)."""
        return {**{e.address: "changing" for _, e in self.changed},
                **{a: "removing" for _, a in self.removed}}

    def said(self) -> str:
        """The plan in words, for the log."""
        parts = [f"{what} {', '.join(map(str, addresses))}" for what, addresses in
                 (("added", [e.address for _, e in self.added]),
                  ("removed", [a for _, a in self.removed]),
                  ("changed", [e.address for _, e in self.changed])) if addresses]
        return "; ".join(parts) or "nothing changed"


def plan(running: GatewayConfig, new: GatewayConfig) -> Plan:
    """What reloading ``new`` over ``running`` does; NeedsRestart if it changes
    anything but the nodes."""
    before = running.model_dump(exclude=set(NODE_KEYS))
    key = _first_difference(before, new.model_dump(exclude=set(NODE_KEYS)))
    if key is not None:
        raise NeedsRestart(_restart(key))
    if len(running.stations) != len(new.stations):
        raise NeedsRestart(_restart("base stations (added or removed)"))
    for (where, station), old in zip(new.placed_stations(), running.stations, strict=True):
        key = _first_difference(old.model_dump(exclude={"nodes"}),
                                station.model_dump(exclude={"nodes"}), where)
        if key is not None:
            raise NeedsRestart(_restart(key))
    was, now = _placed_nodes(running.stations), _placed_nodes(new.stations)
    added, removed, changed = [], [], []
    for address, (station, entry) in now.items():
        old = was.get(address)
        if old is None or old[0] != station:  # (a node moved: off one, onto the other)
            added.append((station, entry))
        elif old[1] != entry:
            changed.append((station, entry))
    for address, (station, _) in was.items():
        if address not in now or now[address][0] != station:
            removed.append((station, address))
    result = Plan(tuple(added), tuple(removed), tuple(changed))
    _nodes_fixed_by_port(new, {s for s, _ in (*added, *removed, *changed)})
    return result


def _restart(key: str) -> str:
    return f"{key} cannot change while the gateway runs: restart it to apply the file"


def _placed_nodes(stations: Iterable[StationConfig]) -> dict[int, tuple[str, NodeEntry]]:
    return {node.address: (station.name or "", node) for station in stations
            for node in station.nodes}


def _nodes_fixed_by_port(config: GatewayConfig, touched: set[str]) -> None:
    """sim:// simulates the nodes configured at start, and replay:// plays what was
    recorded: their nodes change only with a restart."""
    for where, station in config.placed_stations():
        if station.name in touched and station.port.startswith((SIM_SCHEME, REPLAY_SCHEME)):
            raise NeedsRestart(_restart(f"{where}.nodes (its port is {station.port})"))


def _first_difference(old: Any, new: Any, where: str = "") -> str | None:
    """The first key (``publish.endpoint``, ``base_stations[1].port``) whose value
    differs, or None."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in [*old, *(k for k in new if k not in old)]:
            found = _first_difference(old.get(key), new.get(key),
                                      f"{where}.{key}" if where else str(key))
            if found is not None:
                return found
        return None
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for index, (a, b) in enumerate(zip(old, new, strict=True)):
            found = _first_difference(a, b, f"{where}[{index}]")
            if found is not None:
                return found
        return None
    return None if old == new else where


class Reloader:
    """Applies the file at ``path`` to the running gateway, one reload at a time."""

    def __init__(self, path: str | Path, running: Callable[[], GatewayConfig],
                 applied: Callable[[GatewayConfig], None], stations: Stations[Station],
                 health: Health, ops: Operations) -> None:
        self.path = path
        self._running = running
        self._applied = applied
        self._stations = stations
        self._health = health
        self._ops = ops
        self._lock = asyncio.Lock()
        self._tasks: set[asyncio.Task[dict[str, Any]]] = set()
        self._waiting_for: set[int] = set()
        """The nodes whose running operations the reload under way waits for."""

    def soon(self) -> None:
        """SIGHUP: reload in the background (its outcome is logged)."""
        self._start()

    async def reload(self, patience: float | None = None) -> dict[str, Any]:
        """Reload, to the end even if the caller gives up: a reload half applied
        would leave a configuration the file never held. What changed, or Invalid (the
        file does not check) or Refused (it needs a restart), logged in one line.

        Still waiting for an operation on a node it changes after ``patience``
        seconds: ``{"waiting_for": [NODE, ...]}`` at once, and it goes on (logged)."""
        task = self._start()
        if patience is not None:
            await asyncio.wait([task], timeout=patience)
            if not task.done() and self._waiting_for:
                return {"waiting_for": sorted(self._waiting_for)}
        return await asyncio.shield(task)

    def _start(self) -> asyncio.Task[dict[str, Any]]:
        task = asyncio.get_running_loop().create_task(self._reload())
        self._tasks.add(task)
        task.add_done_callback(self._done)
        return task

    def _done(self, task: asyncio.Task[dict[str, Any]]) -> None:
        """A reload ended: a refusal is logged already; a bug is raised here, where
        the loop logs it (its caller, if any, has it too)."""
        self._tasks.discard(task)
        if not task.cancelled() and not isinstance(task.exception(), (Invalid, Refused)):
            task.result()

    def close(self) -> None:
        for task in list(self._tasks):
            task.cancel()

    async def _reload(self) -> dict[str, Any]:
        async with self._lock:
            try:
                new = await read_config(self.path)
                todo = plan(self._running(), new)
            except ConfigError as error:
                log.error("reload refused: %s; %s", error, KEPT)
                raise Invalid(f"reload refused: {error}; {KEPT}") from None
            except NeedsRestart as error:
                log.error("reload refused: %s; %s", error, KEPT)
                raise Refused(f"reload refused: {error}; {KEPT}") from None
            unconfirmed = await self._wait_and_apply(todo) if todo else []
            self._applied(new)
            log.info("reloaded %s: %s", self.path, todo.said() + "".join(
                f"; node {a} not confirmed stopped: {why}" for a, why in unconfirmed))
            return {"added": [e.address for _, e in todo.added],
                    "removed": [a for _, a in todo.removed],
                    "changed": [e.address for _, e in todo.changed],
                    "not_stopped": [{"node": a, "error": why} for a, why in unconfirmed]}

    async def _wait_and_apply(self, todo: Plan) -> list[tuple[int, str]]:
        """An operation on a node it changes ends first (a bias capture, a self-test);
        a new one on such a node is refused meanwhile, so only those running when the
        reload came are waited for. Any other node's goes on untouched."""
        log.info("reload of %s: %s", self.path, todo.said())
        with self._ops.reserved(todo.doing):
            self._waiting_for = self._ops.busy(todo.touched)
            if self._waiting_for:
                log.info("reload of %s waits for the operation on node %s", self.path,
                         ", ".join(map(str, sorted(self._waiting_for))))
            try:
                await self._ops.idle(todo.touched)
            finally:
                self._waiting_for = set()
            return await self._apply(todo)

    async def _apply(self, todo: Plan) -> list[tuple[int, str]]:
        """Gone from the one map first (no op, status or metric sees them any more),
        then the new ones in it and armed, the changed ones armed again; last, each
        removed node's stream stopped (as ``stop`` does) and the node forgotten by its
        station. The nodes not in the plan are never touched."""
        stations, by_name = self._stations, {s.name: s for s in self._stations}
        leaving = []
        for name, address in todo.removed:
            node = stations.remove(address)
            self._health.remove(address)
            leaving.append((by_name[name], node))
        for name, entry in todo.added:
            station = by_name[name]
            node = station.add_node(entry)
            stations.add(station, node)
            self._health.add(node)
            station.supervisor.adopt(node)
        for name, entry in todo.changed:
            station = by_name[name]
            node = station.nodes[entry.address]
            if node.reconfigure(entry):
                station.supervisor.rearm(node)
        results = await asyncio.gather(*(station.retire(node) for station, node in leaving))
        return [(node.address, why) for (_, node), why in zip(leaving, results, strict=True)
                if why is not None]


async def read_config(path: str | Path) -> GatewayConfig:
    """:func:`load_config` in a thread of its own, READ_SECONDS at most: the event loop
    (every stream, every request) never waits for a file. A daemon thread, so a read
    that never returns cannot hold up the gateway's exit."""
    loop = asyncio.get_running_loop()
    future: asyncio.Future[GatewayConfig] = loop.create_future()

    def settle(result: GatewayConfig | None, error: BaseException | None) -> None:
        if future.done():
            return  # (too late: the reload was refused)
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)  # type: ignore[arg-type]

    def read() -> None:
        try:
            outcome: tuple[Any, BaseException | None] = (load_config(path), None)
        except BaseException as error:  # (handed to the loop)
            outcome = (None, error)
        with contextlib.suppress(RuntimeError):  # (the loop has closed)
            loop.call_soon_threadsafe(settle, *outcome)

    threading.Thread(target=read, name="reload-read", daemon=True).start()
    try:
        return await asyncio.wait_for(future, READ_SECONDS)
    except TimeoutError:
        raise ConfigError(f"{path}: not read within {READ_SECONDS:g} s (a FIFO, or a "
                          "file system that does not answer?)") from None
