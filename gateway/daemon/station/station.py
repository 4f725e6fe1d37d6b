"""One base station: everything of the gateway that belongs to one serial port.

Its port and link, the reader of its bytes, the scheduler of its commands, the
supervisor of its nodes, their states and clocks, and how full its line is. Nothing
here is shared with another station, so one unplugged, stalled, flooded with garbage or
replaying slowly never delays another's records or commands: each link's reads arrive
on the loop as its own callbacks, each scheduler has its own one command in flight.
What the gateway has once (its outputs, control, health) is handed in as the small
protocols of :mod:`.outlet`, and a record's way stays one-way: link -> reader -> node ->
the outlet (the gateway's outputs). No module of this package imports an output.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from aspp.timing import BITS_PER_BYTE, byte_time

from ..config import NodeEntry, StationConfig
from ..health import SAMPLE_PERIOD
from .lineload import LineLoad, Waited
from .link import SerialLink
from .nodes import Node
from .outlet import Outlet, SerialTap
from .ports import Port
from .reader import Reader
from .replay import ReplayLink
from .replayread import ReplayReaders
from .replaystart import RecordedStart
from .scheduler import Scheduler
from .supervisor import Supervisor

log = logging.getLogger("gx2.gateway")
SILENT_SAMPLES = 2
"""Seconds of a live line reading nothing after which a hold on it ends."""


class Station:
    """One base station's parts; :meth:`open` once the gateway's sockets are bound."""

    def __init__(self, config: StationConfig, publisher: Outlet, *,
                 channels: tuple[str, str], replays_marks: bool,
                 on_link_state: Callable[[Station, bool], None],
                 on_replay_end: Callable[[Station], None], floor_unseen_s: float,
                 replays: ReplayReaders | None = None) -> None:
        """``channels``: its serial channels in a recording, (reads, writes), as the
        gateway names them (:func:`gateway.recording.files.serial_channels`);
        ``replays_marks``: it publishes a replayed recording's marks again (one station
        of a gateway does, so a mark is not published once a station);
        ``floor_unseen_s``: how long its nodes' clocks may go without seeing their floor
        before status gives how late ``time`` may be (health.floor_unseen_s);
        ``replays``: the recordings' readings the gateway's stations share (a recording
        of several stations read once for all)."""
        self.config = config
        self.name = config.name or ""
        self._on_link_state = on_link_state
        self._on_replay_end = on_replay_end
        line_byte = byte_time(config.baudrate)
        self._floor_unseen_s = floor_unseen_s
        self.nodes = {n.address: self._node(n) for n in config.nodes}
        self.retiring: set[int] = set()
        """Nodes a reload removed whose stream is being stopped: still in :attr:`nodes`
        (their records are the stop's evidence), no longer configured."""
        self.line = LineLoad(config.baudrate / BITS_PER_BYTE, self._waits)
        self.replay = Port.replay_of(config.port)
        self._replays = replays or ReplayReaders()
        self.replaying = self.replay is not None
        self.scheduler = Scheduler(self._write, station=self.name)
        self.supervisor = Supervisor(self.scheduler, self.nodes, passive=self.replaying)
        self.recorded = RecordedStart(publisher, self.nodes) if self.replaying else None
        """A replay's seq and device time, started at the recorded ones
        (:mod:`.replaystart`)."""
        self.reader = Reader(self.nodes, self.recorded or publisher,  # type: ignore[arg-type]
                             self.supervisor, self.scheduler,
                             config.idle_ms / 1000, idle_timer=not self.replaying,
                             byte_time=line_byte, station=self.name)
        self.channels = channels
        """Its serial channels in a recording: (reads, writes)."""
        self._publisher = publisher
        self._replays_marks = replays_marks
        self.recorder: SerialTap | None = None
        self.port: Port | None = None
        self.link: SerialLink | ReplayLink | None = None
        self._opened = False
        """Its port has been open once (later opens are the link's reconnects)."""
        self._on_data: Callable[[bytes, float, float], None] = self.reader.on_data
        self._read_at_sample = 0
        self._silent = 0
        """Samples running (:meth:`sample`) in which its link read nothing."""
        self._said_over = False
        """Whether the log last said its line over capacity."""

    def _node(self, entry: NodeEntry) -> Node:
        return Node(entry, byte_time=byte_time(self.config.baudrate),
                    latency=self.config.latency_ms / 1000, station=self.name,
                    floor_unseen_s=self._floor_unseen_s)

    def add_node(self, entry: NodeEntry) -> Node:
        """A node a reload added: its reader, supervisor and status see it from now on
        (they share :attr:`nodes`), and it is no longer among those heard that are not
        configured; the supervisor arms it (:meth:`Supervisor.adopt`). Its clock is held
        if its line is over capacity (it would learn the queue)."""
        node = self.nodes[entry.address] = self._node(entry)
        self.line.tell(node.clock)
        self.reader.heard.forget(entry.address)
        return node

    async def retire(self, node: Node) -> str | None:
        """A node a reload removed: its stream stopped as ``stop`` stops it (its records
        still read meanwhile, as the stop's evidence), then forgotten. Why it was not
        confirmed stopped, or None."""
        self.retiring.add(node.address)
        try:
            return await self.supervisor.retire(node)
        finally:
            self.retiring.discard(node.address)
            if self.nodes.get(node.address) is node:
                del self.nodes[node.address]

    @property
    def configured(self) -> list[int]:
        """Its nodes' addresses, as its configuration has them now."""
        return [address for address in self.nodes if address not in self.retiring]

    def open(self, recorder: SerialTap | None) -> None:
        """Make its port (an embedded simulator makes a directory: only once nothing of
        the gateway can fail any more) and its link."""
        self.recorder = recorder
        self._on_data = (self.reader.on_data if recorder is None
                         else self._read_and_record)
        self.port = Port(self.config.port, list(self.nodes))
        if self.replay is not None:
            self.link = ReplayLink(self.replay, self._read, self._link_state,
                                   self._replay_ended, self._publisher.replayed,
                                   station=self.name, marks=self._replays_marks,
                                   start=self.recorded,
                                   source=self._replays.of(self.replay))
        else:
            self.link = SerialLink(self.port.path, self.config.baudrate, self._read,
                                   self._link_state)

    def start(self) -> None:
        self.port.start()  # type: ignore[union-attr]
        self.link.start()  # type: ignore[union-attr]

    async def first_try(self) -> None:
        """Until its port's first open has been tried (a replay: at once)."""
        if isinstance(self.link, SerialLink):
            await self.link.tried.wait()

    def _read(self, data: bytes, host_time: float, monotonic: float) -> None:
        """A read (live, or replayed): its line judged first at the seconds before it,
        on the reads' own clock (:meth:`.LineLoad.read`, so a replay holds where live
        did); while it is over capacity, its nodes' clocks learn nothing from the
        backlog (:meth:`aspp.clock.NodeClock.hold`)."""
        before = self.link.bytes_read - len(data)  # type: ignore[union-attr]
        if self.line.read(monotonic, before, SAMPLE_PERIOD):
            self._line_changed()
        self._on_data(data, host_time, monotonic)

    def sample(self) -> None:
        """Once a second, live: a line held over capacity that has read nothing for
        SILENT_SAMPLES seconds running has no queue (a base station with one sends at
        its baud rate): it has room again. Its bins close on its reads, and a line whose
        streams were all stopped while it was held reads nothing more to close one
        with (the line stayed over capacity for good). Two seconds, not one: after a
        host stall this may run before the backlog's read."""
        if self.replaying or self.link is None:
            return
        read = self.link.bytes_read
        self._silent = self._silent + 1 if read == self._read_at_sample else 0
        self._read_at_sample = read
        if self.line.over and self._silent >= SILENT_SAMPLES:
            self.line.link_down()
            self._line_changed()

    def _waits(self) -> list[Waited]:
        """Each node's evidence since the last bin of a queue on its line."""
        return [node.take_wait() for node in self.nodes.values()]

    def _line_changed(self) -> None:
        """Its line went over capacity, has room again, or shows a queue not yet
        confirmed (:attr:`.LineLoad.suspect`), or no longer: its nodes' clocks told (a
        clock already as the line is, a node added meanwhile, is left)."""
        line = self.line
        if line.over != self._said_over:
            self._said_over = line.over
            log.warning("base station %s: %s", self.name, line.reason()
                        if line.over else "line has room again")
        for node in self.nodes.values():
            line.tell(node.clock)

    def close(self) -> None:
        """Close its link (a request still running fails as with the base station gone,
        not as a write to a closed port), then its port."""
        if self.link is not None:
            self.link.close()
        self.scheduler.on_link_down()
        if self.port is not None:
            self.port.close()

    def _write(self, data: bytes) -> None:
        self.link.write(data)  # type: ignore[union-attr]
        if self.recorder is not None:
            self.recorder.sent(data, time.time(), time.monotonic(), self.channels[1])

    def _read_and_record(self, data: bytes, host_time: float, monotonic: float) -> None:
        self.recorder.serial(data, host_time, monotonic, self.channels[0])  # type: ignore[union-attr]
        self.reader.on_data(data, host_time, monotonic)

    def _link_state(self, up: bool) -> None:
        if up and not self._opened:
            self._opened = True
            log.info("base station %s open on %s", self.name, self.config.port)
        self.scheduler.link_up = up
        if up:
            self.reader.line_opened()
        else:
            self.scheduler.on_link_down()
            if self.line.over or self.line.suspect:  # (its queue went with it)
                self.line.link_down()
                self._line_changed()
        self.supervisor.link_changed(up)
        self._on_link_state(self, up)

    def _replay_ended(self) -> None:
        self.reader.end_of_input()
        self._on_replay_end(self)
