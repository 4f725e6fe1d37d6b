"""The gateway: the parts wired together, and their life from start to shutdown.

One asyncio loop owns the serial port, the PUB and ROUTER sockets and every timer, so
no socket is ever touched by two threads. Data flows one way:
:mod:`~gateway.daemon.link` (bytes in) -> :mod:`~gateway.daemon.reader` (decoded,
tallied by :mod:`~gateway.daemon.nodes`) -> :mod:`~gateway.daemon.publisher`. Control
requests go :mod:`~gateway.daemon.control` -> :mod:`~gateway.daemon.operations` ->
:mod:`~gateway.daemon.scheduler` -> serial writes, their replies coming back through
the reader; :mod:`~gateway.daemon.supervisor` keeps each node doing what it should.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import time
from typing import TYPE_CHECKING, Any

import zmq
import zmq.asyncio
from zmq.auth.asyncio import AsyncioAuthenticator

from aspp.timing import BITS_PER_BYTE, byte_time
from gateway.common.curve import AllowList, KeyPair
from gateway.common.version import VERSION
from gateway.recording.files import PARTIAL

from . import status
from .config import GatewayConfig
from .control import ControlServer
from .health import SAMPLE_PERIOD, Health
from .link import SerialLink
from .nodes import Node
from .operations import Operations
from .ports import Port
from .publisher import Publisher
from .reader import Reader
from .recorder import Recorder
from .replay import ReplayLink
from .scheduler import Scheduler
from .sd_notify import Notifier
from .supervisor import Supervisor

if TYPE_CHECKING:
    from .metrics import MetricsServer

log = logging.getLogger("gx2.gateway")
EXIT_PROMISE = 2.0
"""Seconds from SIGTERM or SIGINT to the process's exit (README)."""
AFTER_LOOP = 0.2
"""Of those, what the process may take once the loop has stopped (the interpreter's
exit): the loop's shutdown ends this long before them. The whole shutdown, loop and
all, took 16 ms here (tests/e2e/test_shutdown.py, recording): room for a loaded host."""
EXIT_BUDGET = 1.5
"""Seconds a shutdown may spend stopping streams, within the promised 2 s."""


class StartupError(Exception):
    """The gateway cannot start (an endpoint cannot be bound): one line, exit 1."""


class Gateway:
    def __init__(self, config: GatewayConfig) -> None:
        self.config = config
        self.started = time.time()
        station = config.base_station
        self.nodes = {n.address: Node(n, byte_time=byte_time(station.baudrate),
                                      latency=station.latency_ms / 1000)
                      for n in config.nodes}
        self.health = Health(self.nodes.values(), config.health,
                             station.baudrate / BITS_PER_BYTE)
        self.systemd = Notifier()
        self._ready = False
        self._context = zmq.asyncio.Context()
        server: KeyPair | None = None
        self.allow_list: AllowList | None = None
        self._auth: AsyncioAuthenticator | None = None
        if config.curve is not None:  # ZAP first: no connection is ever let in unchecked
            server = config.curve.server_pair()
            self.allow_list = AllowList(config.curve.allowed())
            self._auth = AsyncioAuthenticator(self._context)
            self._auth.start()
            self._auth.configure_curve_callback("*", self.allow_list)
        # checked by the configuration already: this cannot fail, and opens nothing
        replay = Port.replay_of(station.port)
        self.replaying = replay is not None
        self.scheduler = Scheduler(self._write)
        self.supervisor = Supervisor(self.scheduler, self.nodes, passive=self.replaying)
        self.ops = Operations(self.scheduler, self.supervisor, self.status,
                              allow_eeprom_write=config.control.allow_eeprom_write,
                              allow_any_eeprom_address=config.control.allow_any_eeprom_address,
                              replaying=self.replaying,
                              publish_mark=lambda mark: self.publisher.mark(mark))
        endpoint = config.publish.endpoint
        try:
            self.publisher = Publisher(self._context, endpoint, config.publish.high_water_mark,
                                       server if config.curve and config.curve.publish
                                       else None)
            endpoint = config.control.endpoint
            self.control = ControlServer(self._context, endpoint, self.ops, server)
            self.metrics: MetricsServer | None = None
            if config.metrics is not None:
                # imported only when configured: prometheus-client takes 64 ms to import
                # and 1.8 MiB of memory (python -X importtime; VmRSS before and after)
                from .metrics import MetricsServer
                endpoint = config.metrics.endpoint
                self.metrics = MetricsServer(endpoint)
        except (zmq.ZMQError, OSError) as error:
            self._stop_auth()
            self._context.destroy(linger=0)
            raise StartupError(f"cannot bind {endpoint}: {error.strerror or error}") from None
        self.reader = Reader(self.nodes, self.publisher, self.supervisor, self.scheduler,
                             config.base_station.idle_ms / 1000, idle_timer=not replay,
                             byte_time=byte_time(station.baudrate))
        self.recorder: Recorder | None = None
        on_data = self.reader.on_data
        if config.record is not None:
            self.recorder = Recorder(config.record, self._recording_metadata())
            self.health.recorder = self.recorder
            self.publisher.record = self.recorder.published
            on_data = self._read_and_record
        # only once nothing above can fail: the embedded simulator makes a directory
        self.port = Port(config.base_station.port, list(self.nodes))
        self.link: SerialLink | ReplayLink
        if replay is not None:
            self.link = ReplayLink(replay, on_data, self._on_link_state, self._replay_ended,
                                   self.publisher.replayed)
        else:
            self.link = SerialLink(self.port.path, config.base_station.baudrate, on_data,
                                   self._on_link_state)
        self._stop: asyncio.Event | None = None
        self.exit_status = 0
        """The process's, once run returns: PARTIAL after a replay (exit=true) that
        skipped something it could not read."""
        self._reported = 0.0
        """time.monotonic() of the last status report."""

    # -- running --------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        self._stop = stop
        if self.recorder is not None:
            self.recorder.start()
        self.port.start()
        self.link.start()
        if self.link.up:
            log.info("base station %s open", self.config.base_station.port)
        loop = asyncio.get_running_loop()
        tasks = [loop.create_task(self.control.serve()), loop.create_task(self._heartbeat()),
                 loop.create_task(self._sample()),
                 loop.create_task(self.supervisor.watch_streams())]
        if self.systemd.watchdog_interval:
            tasks.append(loop.create_task(self._watchdog(self.systemd.watchdog_interval)))
        log.info("publishing on %s, control on %s, %d nodes", self.config.publish.endpoint,
                 self.config.control.endpoint, len(self.nodes))
        # everything still alive now lives as long as the process: out of the
        # collector's sight, a full collection no longer walks it (here ~20 ms of
        # stalled records each time, for some 35,000 objects of modules, configuration
        # and sockets). The garbage of starting up is collected first.
        gc.collect()
        gc.freeze()
        try:
            await stop.wait()
        finally:
            # the promise runs from here (the signal's handler set ``stop``)
            done_by = time.monotonic() + EXIT_PROMISE - AFTER_LOOP
            self.systemd.stopping()
            for task in tasks:
                task.cancel()
            await self._shutdown(done_by)

    async def _shutdown(self, done_by: float) -> None:
        """Close everything by ``done_by`` (time.monotonic())."""
        loop = asyncio.get_running_loop()
        metrics = (loop.run_in_executor(None, self.metrics.close)  # (up to 0.5 s: meanwhile)
                   if self.metrics is not None else None)
        # nothing more is started for any node; then every request still running is
        # answered at once ("shutting down") and cancelled: its client hears why now,
        # not at its own timeout, and what a cancelled quiet command would have
        # started again afterwards is not (issue 19)
        self.supervisor.close()
        self.control.close()
        self.ops.close()
        if self.config.shutdown.stop_streams and self.link.up and not self.replaying:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.supervisor.stop_all_streams(), EXIT_BUDGET)
        self.link.close()
        # what a cancelled request still sends on its way out (a self-test switching
        # BIT off) fails as with the base station gone, not as a write to a closed port
        self.scheduler.on_link_down()
        self.publisher.close()
        self._stop_auth()
        self._context.destroy(linger=0)  # (the answers above: up to CLOSE_LINGER_MS)
        self.port.close()
        if self.recorder is not None:
            # off the loop, which has nothing left to do: the last second, and the index,
            # in what is left of the promise (the recorder says what the file holds if
            # the disk is slower)
            await loop.run_in_executor(None, self.recorder.close,
                                       max(0.0, done_by - time.monotonic()))
        if metrics is not None:
            await metrics
        log.info("stopped")

    def _stop_auth(self) -> None:
        if self._auth is not None:
            self._auth.stop()
            self._auth = None

    def _write(self, data: bytes) -> None:
        self.link.write(data)
        if self.recorder is not None:
            self.recorder.sent(data, time.time(), time.monotonic())

    def _read_and_record(self, data: bytes, host_time: float, monotonic: float) -> None:
        self.recorder.serial(data, host_time, monotonic)  # type: ignore[union-attr]
        self.reader.on_data(data, host_time, monotonic)

    def _recording_metadata(self) -> dict[str, str]:
        """What a recording says about the gateway that made it."""
        config = self.config
        return {"version": VERSION, "port": config.base_station.port,
                "baudrate": str(config.base_station.baudrate),
                "latency_ms": f"{config.base_station.latency_ms:g}",
                "nodes": json.dumps([{"address": n.address, "name": n.name,
                                      "stream": n.stream} for n in config.nodes])}

    def _replay_ended(self) -> None:
        self.reader.end_of_input()
        self.publisher.status(self.status())
        if self.port.replay is not None and self.port.replay.exit and self._stop is not None:
            log.info("the recording is done: exiting (exit=true)")
            if isinstance(self.link, ReplayLink) and self.link.partial:
                self.exit_status = PARTIAL
            self._stop.set()

    def _on_link_state(self, up: bool) -> None:
        self.scheduler.link_up = up
        if up and not self._ready:
            # READY only now: the sockets were bound before the port could open
            self._ready = True
            self.systemd.ready(f"{len(self.nodes)} nodes on {self.config.base_station.port}")
        self.systemd.status("base station " + ("connected" if up else "disconnected, "
                                               "reconnecting"))
        if not up:
            self.scheduler.on_link_down()
        self.supervisor.link_changed(up)
        self.publisher.status(self.status())

    # -- status ---------------------------------------------------------------------------

    async def _watchdog(self, interval: float) -> None:
        """WATCHDOG=1 while the loop runs and the link is up or being reopened: a stuck
        loop, or a reopen loop that died, stops the pings and systemd restarts us."""
        while True:
            if self.link.up or self.link.reopening:
                self.systemd.watchdog()
            await asyncio.sleep(interval)

    async def _heartbeat(self) -> None:
        while True:
            await asyncio.sleep(self.config.publish.heartbeat_s)
            self.publisher.status(self.status())

    async def _sample(self) -> None:
        """Once a second: the counters each node's health is judged over, and a report
        for the metrics endpoint if none was made in that second (the heartbeat's)."""
        while True:
            now = time.monotonic()
            self.health.sample(now, self.link.bytes_read)
            if self.metrics is not None and now - self._reported >= SAMPLE_PERIOD:
                self.status()
            await asyncio.sleep(SAMPLE_PERIOD)

    def status(self) -> dict[str, Any]:
        """The status report (and the one the metrics endpoint serves from now on)."""
        report = status.report(self)
        if self.metrics is not None:
            self.metrics.update(report)
            self._reported = time.monotonic()
        return report
