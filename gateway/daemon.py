"""The gateway: one asyncio loop owning the serial port, the PUB and ROUTER sockets and
every timer, so no socket is ever touched by two threads.

Data flows one way: bytes from :mod:`gateway.link` -> :class:`aspp.Decoder` events ->
:class:`gateway.nodes.NodeState` payloads -> :mod:`gateway.publisher`. Control requests
go :mod:`gateway.control` -> :mod:`gateway.operations` -> :mod:`gateway.scheduler` ->
serial writes, and their replies come back through the same decoder.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import shutil
import time
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import zmq
import zmq.asyncio
from zmq.auth.asyncio import AsyncioAuthenticator

from aspp import Ack, Decoder, Frame, Nack, PingOk, Reply, commands, decode
from aspp.errors import RecordError
from aspp.frame import HEADER_SIZE

from .config import GatewayConfig
from .control import ControlServer
from .curve import AllowList, KeyPair
from .link import SerialLink, embedded_link_path, simulator_for
from .nodes import Delivery, NodeState
from .operations import Operations
from .publisher import Publisher
from .scheduler import Scheduler
from .sd_notify import Notifier
from .sim.server import Simulator

log = logging.getLogger("gx2.gateway")
EXIT_BUDGET = 1.5
"""Seconds a shutdown may spend stopping streams, within the promised 2 s."""
WATCH_MIN_SLEEP = 0.25
"""The least the stream watcher sleeps; also how long a stall's backlog is given to be
read before any stream is judged silent."""
WATCH_MAX_SLEEP = 1.0
"""The most it sleeps: no stream armed meanwhile can fall silent sooner (SILENCE_MIN)."""
_new_tuple = tuple.__new__  # a Delivery without NamedTuple's Python-level __new__

try:
    VERSION = version("gx2-gateway")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    VERSION = "unknown"


class StartupError(Exception):
    """The gateway cannot start (an endpoint cannot be bound): one line, exit 1."""


class Gateway:
    def __init__(self, config: GatewayConfig) -> None:
        self.config = config
        self.nodes = {n.address: NodeState(n) for n in config.nodes}
        self.decoder = Decoder()
        self.started = time.time()
        self.unknown_node_packets = 0
        self.bad_records = 0
        self.simulator: Simulator | None = None
        self._idle: asyncio.TimerHandle | None = None
        self._arming: dict[int, asyncio.Task[None]] = {}
        self.systemd = Notifier()
        self._ready = False
        self._context = zmq.asyncio.Context()
        self.link = SerialLink(config.base_station.port, config.base_station.baudrate,
                               self._on_data, self._on_link_state)
        self.scheduler = Scheduler(self.link.write)
        self.ops = Operations(self.scheduler, self.nodes, config.control.allow_eeprom_write,
                              config.control.allow_any_eeprom_address)
        server: KeyPair | None = None
        self.allow_list: AllowList | None = None
        self._auth: AsyncioAuthenticator | None = None
        if config.curve is not None:  # ZAP first: no connection is ever let in unchecked
            server = config.curve.server_pair()
            self.allow_list = AllowList(config.curve.allowed())
            self._auth = AsyncioAuthenticator(self._context)
            self._auth.start()
            self._auth.configure_curve_callback("*", self.allow_list)
        endpoint = config.publish.endpoint
        try:
            self.publisher = Publisher(self._context, endpoint, config.publish.high_water_mark,
                                       server if config.curve and config.curve.publish
                                       else None)
            endpoint = config.control.endpoint
            self.control = ControlServer(self._context, endpoint, self.ops, self.status,
                                         server)
        except zmq.ZMQError as error:
            self._stop_auth()
            self._context.destroy(linger=0)
            raise StartupError(f"cannot bind {endpoint}: {error.strerror}") from None
        if config.base_station.port.startswith("sim://"):  # only once nothing can fail
            self._sim_link = embedded_link_path()
            self.simulator = simulator_for(config.base_station.port, list(self.nodes),
                                           self._sim_link)
            self.link.port = str(self._sim_link)

    # -- running --------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        if self.simulator is not None:
            self.simulator.start()
        try:
            self.link.open()
            log.info("base station %s open", self.config.base_station.port)
        except OSError as error:
            log.warning("base station %s: %s; retrying", self.config.base_station.port, error)
            self.link.start_reopening()
        loop = asyncio.get_running_loop()
        tasks = [loop.create_task(self.control.serve()), loop.create_task(self._heartbeat()),
                 loop.create_task(self._watch_streams())]
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
            self.systemd.stopping()
            for task in tasks:
                task.cancel()
            await self._shutdown()

    async def _shutdown(self) -> None:
        for task in self._arming.values():
            task.cancel()
        if self.config.shutdown.stop_streams and self.link.up:
            streaming = [n for n in self.nodes.values() if n.record]
            stops = [self.ops.send(n, commands.stop_continuous(), wait_for_reply=False)
                     for n in streaming]
            with contextlib.suppress(Exception):
                await asyncio.wait_for(asyncio.gather(*stops, return_exceptions=True),
                                       EXIT_BUDGET)
        self.control.close()
        self.link.close()
        self.publisher.close()
        self._stop_auth()
        self._context.destroy(linger=0)
        if self.simulator is not None:
            self.simulator.stop()
            shutil.rmtree(self._sim_link.parent, ignore_errors=True)
        log.info("stopped")

    def _stop_auth(self) -> None:
        if self._auth is not None:
            self._auth.stop()
            self._auth = None

    # -- the serial side ------------------------------------------------------------------

    def _on_data(self, data: bytes, host_time: float) -> None:
        self._dispatch(self.decoder.feed(data), host_time)
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        if self.decoder.pending:
            self._idle = asyncio.get_running_loop().call_later(
                self.config.base_station.idle_ms / 1000, self._line_idle, host_time)

    def _line_idle(self, host_time: float) -> None:
        self._idle = None
        self._dispatch(self.decoder.line_idle(), host_time)

    def _dispatch(self, events: list[Any], host_time: float) -> None:
        scheduler = self.scheduler
        for event in events:
            kind = type(event)
            if kind is Reply:
                self._on_reply(event, host_time)
            elif kind is Ack:
                scheduler.on_ack()
            elif kind is Nack:
                scheduler.on_nack()
            elif kind is PingOk:
                scheduler.on_ping_ok()
            elif kind is Frame and event.is_discovery:
                self._on_discovery(event.node)

    def _on_reply(self, event: Reply, host_time: float) -> None:
        """One reply record: count it, publish it, and hand it to whoever waits for it.
        (The per-record path: every step here runs several hundred times a second.)"""
        node = self.nodes.get(event.node)
        if node is None:
            self.unknown_node_packets += 1
            return
        raw = event.raw
        try:
            record = decode(raw, HEADER_SIZE, len(raw) - 4)  # (event.payload, in place)
        except RecordError as error:
            self.bad_records += 1
            log.debug("node %d: %s", event.node, error)
            return
        spec = record.spec
        payload = node.payload(event, record, host_time)
        if not self.publisher.publish(node.address, spec.name, payload):
            node.lost_gateway += 1
        if node.quiet_reboot:
            node.quiet_reboot = False
            log.warning("node %s rebooted (its timer went back)", node.config.label)
            self._arm(node)
        elif node.state == "unreachable" and spec.name == node.config.stream:
            self._stream_resumed(node)
        if node.stop_policy is not None and spec.code == 0xC4 and record.values[0] == 0:
            node.stop_policy.stop_confirmed(time.monotonic())
        self.scheduler.on_reply(node.address, spec.code, _new_tuple(Delivery, (record, payload)))

    def _on_discovery(self, address: int) -> None:
        node = self.nodes.get(address)
        if node is None:
            return
        log.warning("node %s rebooted (discovery packet)", node.config.label)
        node.rebooted()
        self._arm(node)

    def _on_link_state(self, up: bool) -> None:
        self.scheduler.link_up = up
        if up and not self._ready:
            # READY only now: the sockets were bound before the port could open
            self._ready = True
            self.systemd.ready(f"{len(self.nodes)} nodes on {self.config.base_station.port}")
        self.systemd.status("base station " + ("connected" if up else "disconnected, "
                                               "reconnecting"))
        if up:
            for node in self.nodes.values():
                self._arm(node)
        else:
            self.scheduler.on_link_down()
            for node in self.nodes.values():
                node.link_lost()
        self.publisher.status(self.status())

    def _stream_resumed(self, node: NodeState) -> None:
        """The configured stream is back while its re-arm waits out a backoff (the node
        was out of range, not rebooted): the stream needs nothing more."""
        task = self._arming.pop(node.address, None)
        if task is not None:
            task.cancel()
        node.streaming(node.config.stream)
        log.info("node %s: its stream came back by itself", node.config.label)

    async def _watch_streams(self) -> None:
        """A stream that fell silent (a reboot whose discovery packet was lost, or the
        node out of range) is counted and its configured stream re-armed. A timer, not
        a tick: it sleeps until the earliest moment a stream could fall silent."""
        while True:
            now = time.monotonic()
            due = min((at for node in self.nodes.values()
                       if (at := node.silent_at()) is not None), default=now + WATCH_MAX_SLEEP)
            delay = min(max(due - now, WATCH_MIN_SLEEP), WATCH_MAX_SLEEP)
            await asyncio.sleep(delay)
            woke = time.monotonic()
            stalled = woke - now > delay + WATCH_MIN_SLEEP
            if stalled or not self.link.up:  # (after a stall of this process the bytes
                continue                    # it has not read yet may hold the records)
            for node in self.nodes.values():
                if node.fell_silent(woke):
                    log.warning("node %s: its %s stream fell silent", node.config.label,
                                node.record)
                    if node.config.stream is not None:
                        self._arm(node)

    def _arm(self, node: NodeState) -> None:
        """(Re)start the node's configured stream in the background."""
        if node.config.stream is None:
            node.state = "streaming" if node.record else "polled"  # a user's stream
            return
        old = self._arming.pop(node.address, None)
        if old is not None:
            old.cancel()
        self._arming[node.address] = asyncio.get_running_loop().create_task(
            self.ops.arm(node))

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

    def status(self) -> dict[str, Any]:
        now = time.time()
        stats = self.decoder.stats
        return {
            "gateway": {"version": VERSION, "uptime": round(now - self.started, 3),
                        "time": now, "publish_endpoint": self.config.publish.endpoint,
                        "control_endpoint": self.config.control.endpoint,
                        "published": self.publisher.sent,
                        "publish_failures": self.publisher.failed,
                        "control_requests": self.control.requests,
                        "control_rejected": self.control.rejected,
                        "control_dropped": self.control.dropped,
                        "curve_denied": self.allow_list.denied if self.allow_list else 0,
                        "publish_curve": bool(self.config.curve and
                                              self.config.curve.publish)},
            "link": {"port": self.config.base_station.port,
                     "state": "up" if self.link.up else "down", "since": self.link.since,
                     "reconnects": self.link.reconnects, "bytes_read": self.link.bytes_read,
                     "error": self.link.last_error,
                     "discarded_bytes": stats.bytes_discarded,
                     "discarded": {str(k): v for k, v in stats.discarded_bytes.items()},
                     "unknown_node_packets": self.unknown_node_packets,
                     "bad_records": self.bad_records,
                     "retries": self.scheduler.stats.retries,
                     "failures": self.scheduler.stats.failures,
                     "unexpected_answers": self.scheduler.stats.unexpected},
            "nodes": [node.status(now) for node in self.nodes.values()],
        }
