"""The daemon's own parts wired to gx2-sim's base station in memory: no pty, no thread,
no subprocess, so tests of the operations, the supervisor and the control server run
in milliseconds against a base station and nodes that answer as the real ones do.

The reader, scheduler, supervisor and operations are the daemon's; the serial line is
a call into :class:`gateway.sim.base_station.BaseStation` (pure: it is given the time),
pumped by a task on the test's event loop; the publisher only records what it is given.
"""

from __future__ import annotations

import asyncio
import random
import time
from typing import Any

from gateway.daemon.config import NodeEntry
from gateway.daemon.operations import Operations
from gateway.daemon.requests import MODELS
from gateway.daemon.station.nodes import Node
from gateway.daemon.station.reader import Reader
from gateway.daemon.station.scheduler import Scheduler
from gateway.daemon.station.supervisor import Supervisor
from gateway.sim.base_station import BaseStation, LineFaults, RadioLink
from gateway.sim.node import NodeSettings, SimNode

PUMP = 0.002
"""The longest the pump sleeps (sooner when the base station has something due)."""


class RecordingPublisher:
    """Stands in for the PUB socket: keeps (node, record, payload) in order."""

    def __init__(self) -> None:
        self.published: list[tuple[int, str, dict[str, Any]]] = []

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        self.published.append((node, record, payload))
        return True

    def records(self, node: int, record: str | None = None) -> list[dict[str, Any]]:
        return [p for n, r, p in self.published
                if n == node and (record is None or r == record)]


def one_node_reader(idle: float = 0.03, **options: Any) -> tuple[Reader, RecordingPublisher]:
    """A reader of one station with node 76 configured and streaming accel_angrate at
    100 Hz; ``options`` for :class:`Reader` (station, byte_time, ...)."""
    nodes = {76: Node(NodeEntry(address=76))}
    nodes[76].streaming("accel_angrate", 512)
    scheduler = Scheduler(lambda data: None)
    publisher = RecordingPublisher()
    return Reader(nodes, publisher, Supervisor(scheduler, nodes), scheduler,  # type: ignore[arg-type]
                  idle, idle_timer=False, **options), publisher


class Wired:
    """``async with Wired([NodeSettings(76)], [{"address": 76}]) as gw: ...``"""

    def __init__(self, simulated: list[NodeSettings], configured: list[dict[str, Any]], *,
                 radio: dict[int, RadioLink] | None = None, line: LineFaults | None = None,
                 allow_eeprom_write: bool = False, seed: int = 1) -> None:
        now = time.monotonic()
        rng = random.Random(seed)
        self.station = BaseStation([SimNode(s, now, random.Random(rng.random()))
                                    for s in simulated], radio, line, rng=rng)
        self.nodes = {n["address"]: Node(NodeEntry(**n)) for n in configured}
        self.scheduler = Scheduler(self._write)
        self.supervisor = Supervisor(self.scheduler, self.nodes)
        self.publisher = RecordingPublisher()
        self.reader = Reader(self.nodes, self.publisher, self.supervisor,  # type: ignore[arg-type]
                             self.scheduler, idle_seconds=0.03)
        self.replaying = False
        self.name = "station1"
        self.ops = Operations([self], lambda: {"status": "ok"},
                              allow_eeprom_write=allow_eeprom_write)
        self._pump: asyncio.Task[None] | None = None

    def node(self, address: int) -> SimNode:
        return self.station.nodes[address]

    async def run(self, op: str, **fields: Any) -> dict[str, Any]:
        """Run one control op as the control server would (validated first)."""
        return await self.ops.run(MODELS[op].model_validate({"id": 1, "op": op, **fields}))

    def _write(self, data: bytes) -> None:
        self.station.from_host(data, time.monotonic())

    async def _run(self) -> None:
        while True:
            now = time.monotonic()
            self.station.advance(now)
            out = self.station.take_output(now)
            if out:
                self.reader.on_data(out, time.time(), time.monotonic())
            await asyncio.sleep(max(0.0, min(self.station.next_due(now) - time.monotonic(),
                                             PUMP)))

    def link(self, up: bool) -> None:
        self.scheduler.link_up = up
        if not up:
            self.scheduler.on_link_down()
        self.supervisor.link_changed(up)

    async def __aenter__(self) -> Wired:
        self._pump = asyncio.get_running_loop().create_task(self._run())
        self.link(True)
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.supervisor.close()
        if self._pump is not None:
            self._pump.cancel()
            await asyncio.wait([self._pump])
