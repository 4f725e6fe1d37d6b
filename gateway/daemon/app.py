"""The gateway: its base stations wired to what it has once, and their life from start
to shutdown.

One asyncio loop owns every serial port, the PUB and ROUTER sockets and every timer, so
no socket is ever touched by two threads. Each base station is a
:class:`~gateway.daemon.station.station.Station` of its own (link, reader, scheduler,
supervisor, nodes); the gateway has one set of outputs (:mod:`~gateway.daemon.outputs`:
ZeroMQ, and the recorder, live view and metrics when configured), one control endpoint
and one health. Data flows one way: a station's :mod:`~gateway.daemon.station.link`
(bytes in) -> :mod:`~gateway.daemon.station.reader` (decoded, tallied by
:mod:`~gateway.daemon.station.nodes`) -> the outputs' fan-out -> every output. Control
requests go :mod:`~gateway.daemon.control` ->
:mod:`~gateway.daemon.operations` -> the node's station's
:mod:`~gateway.daemon.station.scheduler` -> its serial writes, their replies coming back
through its reader; its :mod:`~gateway.daemon.station.supervisor` keeps each node doing what it
should.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zmq
import zmq.asyncio
from zmq.auth.asyncio import AsyncioAuthenticator

from gateway.common.curve import AllowList, KeyPair
from gateway.common.version import installed
from gateway.recording.files import PARTIAL, serial_channels

from . import status
from .config import GatewayConfig
from .control import ControlServer
from .errors import StartupError
from .health import SAMPLE_PERIOD, Health
from .operations import Operations
from .outputs import Needs, Output, Outputs, build, close_built
from .outputs.frames import Frames
from .outputs.guard import Guard
from .reload import Reloader
from .sd_notify import Notifier
from .station.replay import ReplayLink
from .station.replayread import ReplayReaders
from .station.station import Station
from .stations import Stations

if TYPE_CHECKING:
    from .outputs.recorder import Recorder
    from .outputs.zeromq import Publisher

log = logging.getLogger("gx2.gateway")
EXIT_PROMISE = 2.0
"""Seconds from SIGTERM or SIGINT to the process's exit (docs/gateway.md)."""
AFTER_LOOP = 0.2
"""Of those, what the process may take once the loop has stopped (the interpreter's
exit): the loop's shutdown ends this long before them. The whole shutdown, loop and
all, took 16 ms here (tests/e2e/test_shutdown.py, recording): room for a loaded host."""
EXIT_BUDGET = 1.5
"""Seconds a shutdown may spend stopping streams, within the promised 2 s."""


class Gateway:
    def __init__(self, config: GatewayConfig, path: str | Path | None = None) -> None:
        """``path``: the file ``config`` was read from, which a reload reads again."""
        self.config = config
        self.started = time.time()
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
        built: dict[str, Output] = {}
        guard = Guard()
        try:
            built = build(Needs(config, self._context, server, self._recording_metadata,
                                guard))
            self.outputs = Outputs(built, Frames(self._name_of), guard)
            replays = ReplayReaders()  # (a recording of several stations: read once)
            self.stations = Stations(
                Station(station, self.outputs,
                        channels=serial_channels(None if len(config.stations) == 1
                                                 else station.name),
                        replays_marks=index == 0, on_link_state=self._on_link_state,
                        on_replay_end=self._replay_ended,
                        floor_unseen_s=config.health.floor_unseen_s, replays=replays)
                for index, station in enumerate(config.stations))
            self.nodes = self.stations.nodes
            self.replaying = self.stations.replaying
            self.ops = Operations(self.stations, self.status,
                                  allow_eeprom_write=config.control.allow_eeprom_write,
                                  allow_any_eeprom_address=config.control.allow_any_eeprom_address,
                                  publish_mark=self._mark)
            endpoint = config.control.endpoint
            try:
                self.control = ControlServer(self._context, endpoint, self.ops, server)
            except (zmq.ZMQError, OSError) as error:
                raise StartupError(f"cannot bind {endpoint}: {error.strerror or error}") \
                    from None
        except StartupError:
            close_built(built.values())  # (the live view and metrics serve already)
            self._stop_auth()
            self._context.destroy(linger=0)
            raise
        self.publisher: Publisher = self.outputs.by_name["zeromq"]  # type: ignore[assignment]
        """The ZeroMQ output: what status counts as published."""
        self.recorder: Recorder | None = self.outputs.get("recording")  # type: ignore[assignment]
        self.health = Health(self.nodes.values(), config.health,
                             lines=[(None if len(self.stations) == 1 else station.name,
                                     station.line) for station in self.stations],
                             recorder=self.recorder,
                             take_failures=self.outputs.take_failures,
                             heard=[(None if len(self.stations) == 1 else station.name,
                                     station.reader.heard) for station in self.stations],
                             owned=lambda: status.owned(self))
        self.reloader: Reloader | None = None
        if path is not None:
            self.reloader = Reloader(path, lambda: self.config, self._reloaded,
                                     self.stations, self.health, self.ops)
            self.ops.reload = self.reloader.reload
        # only once nothing above can fail: the embedded simulator makes a directory
        for station in self.stations:
            station.open(self.recorder)
        self._stop: asyncio.Event | None = None
        self.exit_status = 0
        """The process's, once run returns: PARTIAL after a replay (exit=true) that
        skipped something it could not read."""
        self._reported = 0.0
        """time.monotonic() of the last status report."""

    def _name_of(self, address: int) -> str | None:
        """A node's name as its state says it now (a reload renames, adds and removes
        nodes there): None for a node without one, or not configured."""
        node = self.nodes.get(address)
        return node.name if node is not None else None

    @property
    def station(self) -> Station:
        """The first base station (the only one, in the one-station form)."""
        return self.stations[0]

    # -- running --------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        self._stop = stop
        self.outputs.start()
        for station in self.stations:
            station.start()
        loop = asyncio.get_running_loop()
        tasks = [loop.create_task(self.control.serve()), loop.create_task(self._heartbeat()),
                 loop.create_task(self._sample()),
                 *(loop.create_task(station.supervisor.watch_streams())
                   for station in self.stations)]
        if self.systemd.watchdog_interval:
            tasks.append(loop.create_task(self._watchdog(self.systemd.watchdog_interval)))
        log.info("publishing on %s, control on %s, %d nodes on %d base station%s",
                 self.config.publish.endpoint, self.config.control.endpoint, len(self.nodes),
                 len(self.stations), "" if len(self.stations) == 1 else "s")
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
        # nothing more is started for any node; then every request still running is
        # answered at once ("shutting down") and cancelled: its client hears why now,
        # not at its own timeout, and what a cancelled quiet command would have
        # started again afterwards is not (issue 19)
        if self.reloader is not None:
            self.reloader.close()
        for station in self.stations:
            station.supervisor.close()
        self.control.close()
        self.ops.close()
        if self.config.shutdown.stop_streams:
            # every station's streams at once: the budget is the gateway's, not each one's
            stopping = [station.supervisor.stop_all_streams() for station in self.stations
                        if station.link.up and not station.replaying]  # type: ignore[union-attr]
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.gather(*stopping), EXIT_BUDGET)
        for station in self.stations:
            station.close()
        # every output at once, off the loop, which has nothing left to do: the
        # recording's last second and index, the live view's viewers told, the metrics
        # server stopped, all in what is left of the promise (the recorder says what
        # the file holds if the disk is slower)
        await self.outputs.close(done_by)
        self._stop_auth()
        # (waits for what the control socket and the publisher still send: up to
        # CLOSE_LINGER_MS, and the publisher's seconds from outputs.close)
        self._context.destroy(linger=0)
        log.info("stopped")

    def _stop_auth(self) -> None:
        if self._auth is not None:
            self._auth.stop()
            self._auth = None

    def _recording_metadata(self) -> dict[str, str]:
        """What a recording says about the gateway that made it."""
        config, first = self.config, self.config.stations[0]
        metadata = {"version": installed(), "port": first.port, "baudrate": str(first.baudrate),
                    "latency_ms": f"{first.latency_ms:g}",
                    "nodes": json.dumps([{"address": n.address, "name": n.name,
                                          "stream": n.stream} for n in config.all_nodes])}
        if len(config.stations) > 1:
            metadata["stations"] = json.dumps([
                {"name": s.name, "port": s.port, "baudrate": s.baudrate,
                 "latency_ms": s.latency_ms, "nodes": [n.address for n in s.nodes]}
                for s in config.stations])
        return metadata

    async def _mark(self, payload: dict[str, Any]) -> bool:
        """A mark published, and on the recording's disk before it is answered (the
        recorder's MARK_KEPT_S at most): an export, ``recordings`` or ``Recording`` run
        once ``mark`` returns reads it (issue 43). False if it could not be published."""
        if not self.outputs.mark(payload):
            return False
        if self.recorder is not None and not await self.recorder.kept():
            log.warning("mark %r: not on the recording's disk yet (the disk is slow or "
                        "failing; recording.dropped counts what it loses)",
                        payload.get("text"))
        return True

    def _reloaded(self, config: GatewayConfig) -> None:
        """A reload applied ``config`` (its nodes; nothing else differs): a new
        recording file's metadata says so, and status at once."""
        self.config = config
        self.outputs.status(self.status())

    def _replay_ended(self, station: Station) -> None:
        self.outputs.status(self.status())
        replays = [s.link for s in self.stations if isinstance(s.link, ReplayLink)]
        if not all(link.finished for link in replays):
            return  # (the others' recordings are still playing)
        # every station done, and any of them asked to exit: the order they end in is
        # no matter (a station of a shorter recording or delay ends first)
        asked = any(s.replay is not None and s.replay.exit for s in self.stations)
        if asked and self._stop is not None:
            log.info("the recording is done: exiting (exit=true)")
            if any(link.partial for link in replays):
                self.exit_status = PARTIAL
            self._stop.set()

    def _on_link_state(self, station: Station, up: bool) -> None:
        if up and not self._ready:
            # READY only now: the sockets were bound before a port could open
            self._ready = True
            self.systemd.ready(f"{len(self.nodes)} nodes on "
                               f"{', '.join(s.config.port for s in self.stations)}")
        down = [s.name for s in self.stations if s.link is not None and not s.link.up]
        self.systemd.status("base station" + ("s" if len(self.stations) > 1 else "") +
                            (" connected" if not down else
                             f" disconnected, reconnecting: {', '.join(down)}"
                             if len(self.stations) > 1 else " disconnected, reconnecting"))
        self.outputs.status(self.status())

    # -- status ---------------------------------------------------------------------------

    async def _watchdog(self, interval: float) -> None:
        """WATCHDOG=1 while the loop runs and the link is up or being reopened: a stuck
        loop, or a reopen loop that died, stops the pings and systemd restarts us."""
        while True:
            if all(s.link.up or s.link.reopening for s in self.stations):  # type: ignore[union-attr]
                self.systemd.watchdog()
            await asyncio.sleep(interval)

    async def _heartbeat(self) -> None:
        while True:
            await asyncio.sleep(self.config.publish.heartbeat_s)
            self.outputs.status(self.status())

    async def _sample(self) -> None:
        """Once a second: the counters each node's health is judged over, and a report
        for the metrics endpoint if none was made in that second (the heartbeat's)."""
        # the ports open beside the loop (gateway.daemon.station.offloop), a few milliseconds
        # after start: nothing is judged before each station's first open has been
        # tried, so a port that opens at once never shows its nodes as ERROR ("base
        # station not open yet") for the first second; one that hangs holds this up
        # by SAMPLE_PERIOD at most
        trying = [asyncio.ensure_future(station.first_try()) for station in self.stations]
        await asyncio.wait(trying, timeout=SAMPLE_PERIOD)
        for waiting in trying:
            waiting.cancel()
        while True:
            now = time.monotonic()
            for station in self.stations:  # (each line is judged on its reads, and
                station.sample()  # here only whether it fell silent: Station.sample)
            self.health.sample(now)
            if self.outputs.reads_reports and now - self._reported >= SAMPLE_PERIOD:
                self.status()
            await asyncio.sleep(SAMPLE_PERIOD)

    def status(self) -> dict[str, Any]:
        """The status report (and the one the metrics endpoint serves from now on)."""
        report = status.report(self)
        self.outputs.report(report)
        self._reported = time.monotonic()
        return report
