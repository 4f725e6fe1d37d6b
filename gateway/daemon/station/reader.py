"""What the gateway does with the bytes it reads: the per-record path.

Follow a packet down this file: the link hands over a read and its host time, the
decoder cuts it into events, and each reply record is decoded, tallied by its node
(seq, device time, losses), published, shown to the supervisor (is the node doing what
it should?) and handed to the scheduler (is anyone waiting for it?), in that order and
without climbing back up. ACKs, NACKs and ping answers go to the scheduler; a
discovery packet to the supervisor. A packet from an address not configured here is
counted, remembered among those heard (:mod:`.heard`), and a record of one handed to
whoever listens to that address (a scan reading a node it found): the configured
nodes' records never pay for it.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable

from aspp import Ack, Decoder, Event, Frame, Nack, PingOk, Reply, decode
from aspp.errors import RecordError
from aspp.frame import HEADER_SIZE
from aspp.records import Record
from aspp.timing import BITS_PER_BYTE

from .heard import Heard
from .nodes import Delivery, Node
from .outlet import Publishes
from .scheduler import Scheduler
from .supervisor import Supervisor

log = logging.getLogger("gx2.reader")


class Reader:
    def __init__(self, nodes: dict[int, Node], publisher: Publishes, supervisor: Supervisor,
                 scheduler: Scheduler, idle_seconds: float, idle_timer: bool = True,
                 byte_time: float = BITS_PER_BYTE / 115200, station: str = "") -> None:
        self.decoder = Decoder()
        self.nodes = nodes
        self.publisher = publisher
        self.supervisor = supervisor
        self.scheduler = scheduler
        self.idle_seconds = idle_seconds
        self.byte_time = byte_time
        """Seconds a byte takes on the serial line."""
        self.idle_timer = idle_timer
        """False in a replay: the line's silences are judged by the recorded times only."""
        self._pending_read: tuple[float, float] | None = None
        """When the read that left bytes in the decoder was made."""
        self.unknown_node_packets = 0
        self.heard = Heard(station)
        """The addresses heard that are not configured (:mod:`.heard`)."""
        self.listeners: dict[int, Callable[[Reply, Record], None]] = {}
        """Addresses not configured here that an op listens to: each valid record from
        one is handed to its listener (:func:`gateway.daemon.scanning`)."""
        self.bad_records = 0
        self._idle: asyncio.TimerHandle | None = None
        self._line_free = math.inf
        """When (monotonic) the read was made that held the last packet's last byte: a
        packet that began on the line as that one ended waited behind it, and shows its
        node's clock no floor (:func:`aspp.clock.waited`). Infinite until a packet is
        read after the port opened: the first may have waited behind bytes read before
        it opened (a node whose every packet queues behind another's then showed its
        floor at its first packet, and its age never said it was unseen)."""

    def on_data(self, data: bytes, host_time: float, monotonic: float) -> None:
        """One read from the port, and when it was made: UNIX seconds, and seconds on
        the clock that never steps (the clock estimates run on it)."""
        # A line quiet for idle_seconds has finished what it sent. The timer says so
        # when the line stays quiet; a read that comes after such a silence says so
        # first, whether or not the timer has run yet (a stalled loop runs I/O first).
        # Judged by the reads' own times, a replay of the same reads decodes the same.
        # The gap between two reads is not all silence: the bytes of this read were on
        # the line during it, one byte time each. A loop that stalled (a collection, a
        # busy machine) while the line streamed finds them waiting in the kernel, the
        # rest of a packet it had begun among them, and the line was never quiet: only
        # a gap longer than its bytes' time by idle_seconds holds such a silence. (An
        # earlier version took any gap of idle_seconds for one, and cut that packet.)
        if self._pending_read is not None:
            if self._idle is not None:
                self._idle.cancel()
                self._idle = None
            quiet = monotonic - self._pending_read[1] - len(data) * self.byte_time
            if quiet >= self.idle_seconds:
                self._line_idle()
            self._pending_read = None
        self._dispatch(self.decoder.feed(data), host_time, monotonic)
        if self.decoder.pending:
            self._pending_read = (host_time, monotonic)
            if self.idle_timer:
                self._idle = asyncio.get_running_loop().call_later(self.idle_seconds,
                                                                   self._line_idle)

    def line_opened(self) -> None:
        """The port (re)opened: what the line carried before the first packet read is
        unknown (see _line_free)."""
        self._line_free = math.inf

    def end_of_input(self) -> None:
        """Nothing more will be read (a replay has played its recording)."""
        self._line_idle()

    def _line_idle(self) -> None:
        """The line went quiet after the pending read: what the decoder holds is all."""
        self._idle = None
        read, self._pending_read = self._pending_read, None
        if read is not None:
            self._dispatch(self.decoder.line_idle(), *read)

    def _dispatch(self, events: list[Event], host_time: float, monotonic: float) -> None:
        scheduler = self.scheduler
        for event in events:
            kind = type(event)
            if kind is Reply:
                self._on_reply(event, host_time, monotonic)  # type: ignore[arg-type]
            elif kind is Ack:
                scheduler.on_ack()
            elif kind is Nack:
                scheduler.on_nack()
            elif kind is PingOk:
                scheduler.on_ping_ok()
            else:  # a frame that is no reply, or bytes that framed nothing: either took
                # the line, and a packet after it waited behind it as behind a reply (a
                # bad checksum ahead of each wait let a node's floor count as seen)
                self._line_free = monotonic
                if kind is Frame and event.is_discovery:  # type: ignore[union-attr]
                    node = self.nodes.get(event.node)  # type: ignore[union-attr]
                    if node is not None:
                        self.supervisor.discovery(node)
                    else:
                        self.heard.discovery(event.raw, host_time)  # type: ignore[union-attr]

    def _on_reply(self, event: Reply, host_time: float, monotonic: float) -> None:
        raw = event.raw
        line_free, self._line_free = self._line_free, monotonic
        node = self.nodes.get(event.node)
        if node is None:
            self.unknown_node_packets += 1
            self.heard.reply(event.raw, host_time)
            if self.listeners:
                self._to_listener(event)
            return
        try:
            record = decode(raw, HEADER_SIZE, len(raw) - 4)  # (event.payload, in place)
        except RecordError as error:
            self.bad_records += 1
            log.debug("node %d: %s", event.node, error)
            return
        payload = node.tally(raw, record, host_time, monotonic, line_free)
        if not self.publisher.publish(node.address, record.spec.name, payload):
            node.publish_failed()
        if node.unusual:  # (the next record of a known stream needs no supervision)
            self.supervisor.after_record(node, record)
        if self.scheduler.expects(node.address, record.spec.code):
            self.scheduler.on_reply(node.address, record.spec.code, Delivery(record, payload))

    def _to_listener(self, event: Reply) -> None:
        """A record from an address not configured here, to the op listening to it."""
        listener = self.listeners.get(event.node)
        if listener is None:
            return
        try:
            record = decode(event.payload)
        except RecordError as error:
            self.bad_records += 1
            log.debug("node %d (not configured): %s", event.node, error)
            return
        listener(event, record)
