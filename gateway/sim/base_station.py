"""The simulated USB base station: the serial line on one side, the radio on the other.

From the host it takes command packets and raw pings (:mod:`aspp.host_side` parses them),
answers each packet with ACK or NACK and each ping with 0x02 or 0x21, and forwards
commands over a lossy radio to its nodes. From the nodes it takes reply records, wraps
them in packets with LQI and RSSI, and sends them to the host no faster than the baud
rate allows: each chunk is written when its last byte would have left the UART, and a
base station whose buffer is full drops what arrives. Faults on the line (garbage, bad
checksums, false headers, the ACK glued to the next SOP) are injected here. Pure: the
caller owns the clock and the port.
"""

from __future__ import annotations

import heapq
import random
from collections import deque
from dataclasses import dataclass, field

from aspp.frame import ACK, FLAGS_DISCOVERY, FLAGS_REPLY, NACK, PING, encode_reply_packet
from aspp.host_side import CommandPacket, Garbled, HostStreamDecoder, PingRequest
from aspp.timing import byte_time

from .node import FIRMWARE_VERSION, SimNode

RADIO_LATENCY = 0.003
"""One way over the air, base station to node or back, at the least (seconds): the
floor of every packet's delay, which the gateway's ``latency_ms`` stands for."""
JITTER_MAX = 0.02
"""The random part of a packet's radio delay is cut at this (seconds)."""
PING_TIMEOUT = 0.030
"""How long the base station waits for a node before answering a ping with 0x21."""
GLUE_WAIT = 0.050
"""How long a held ACK waits for a packet to be glued to."""
HOST_LOG = 10_000
"""Command packets and pings from the host remembered for tests (the newest)."""
# The base station's serial output buffer; packets arriving to a full buffer are lost
# (counted: StationStats.packets_dropped_full). The reference gives no size; the base
# station is a small microcontroller between a 250 kbit/s radio and a 115200-baud UART,
# and what matters to the host is that its queue is bounded, as every real one is: at
# 4 KiB a full buffer is 0.36 s of line, so over capacity a packet waits at most that
# long and the rest are lost (a queue without bound would instead make every record
# later than the one before, for ever). ACK, NACK and ping answers are never dropped:
# they are the base station's own answers.
BUFFER_BYTES = 4096


@dataclass
class LineFaults:
    """Faults on the serial line, each a probability per packet sent to the host, and
    the base station's serial output as a model of it describes it."""

    garbage: float = 0.0
    bad_checksum: float = 0.0
    false_header: float = 0.0
    glue_ack: bool = False
    """Hold each ACK and write it in one chunk with the next packet (AA AA 07 ...)."""
    nack: float = 0.0
    """Chance that a well-formed command packet is NACKed anyway (received garbled)
    and not broadcast: the host must send it again."""
    stall_rate: float = 0.0
    """Stalls per second: the base station holds its output back for ``stall_ms``, then
    sends what it held (packets beyond its buffer are lost meanwhile)."""
    stall_ms: float = 50.0
    buffer_bytes: int | None = BUFFER_BYTES
    """The serial output buffer (None: without bound, every packet queued however
    late): what a packet arriving to it full is lost for."""
    throughput: float = 1.0
    """The share of the baud rate the output reaches with a backlog: below 1, an idle
    gap follows each packet (a base station or USB adapter that leaves the line idle
    between packets), and a saturated line reads under its baud rate."""

    def __post_init__(self) -> None:
        if not 0.0 < self.throughput <= 1.0:
            raise ValueError(f"throughput {self.throughput} is not in (0, 1]")
        if self.buffer_bytes is not None and self.buffer_bytes <= 0:
            raise ValueError(f"buffer_bytes {self.buffer_bytes} is not a size")


@dataclass
class RadioLink:
    """One node's radio link: its reach, its losses, its signal."""

    in_range: bool = True
    command_loss: float = 0.0
    data_loss: float = 0.0
    stop_loss: float = 0.0
    """Extra loss for 0xFA alone: a node busy streaming often misses it."""
    lqi: int = 200
    rssi: int = -45
    jitter: float = 0.0005
    """Mean of the random part of a packet's radio delay (exponential, seconds), on top
    of RADIO_LATENCY."""


@dataclass
class StationStats:
    acks: int = 0
    nacks: int = 0
    pings: int = 0
    commands_delivered: int = 0
    commands_lost: int = 0
    packets_sent: dict[int, int] = field(default_factory=dict)
    packets_lost_radio: int = 0
    packets_dropped_full: int = 0
    bytes_sent: int = 0
    faults_injected: int = 0
    stalls: int = 0
    line_idle: float = 0.0
    """Seconds the UART had nothing to send between two chunks (model time, so it does
    not depend on how promptly the simulator's thread runs)."""


class BaseStation:
    def __init__(self, nodes: list[SimNode], radio: dict[int, RadioLink] | None = None,
                 line: LineFaults | None = None, baudrate: int = 115200,
                 rng: random.Random | None = None) -> None:
        self.nodes = {node.address: node for node in nodes}
        self.radio = {a: (radio or {}).get(a, RadioLink()) for a in self.nodes}
        self.line = line or LineFaults()
        self.byte_time = byte_time(baudrate)
        self.rng = rng or random.Random(0)
        self.stats = StationStats()
        self.from_host_log: deque[tuple[float, CommandPacket | PingRequest]] = deque(
            maxlen=HOST_LOG)
        """What the host sent, well formed: (when, packet or ping), newest last."""
        self._host = HostStreamDecoder()
        self._to_nodes: list[tuple[float, int, int, bytes]] = []  # (due, seq, node, command)
        self._answers: list[tuple[float, int, bytes]] = []        # (due, seq, byte)
        self._seq = 0
        self._out: deque[tuple[float, bytes]] = deque()  # (written at, chunk)
        self._line_free_at = 0.0
        self._held_ack_since: float | None = None
        self._held_acks = 0
        self._arrived: dict[int, float] = {}  # node -> when its last packet arrived
        self._in_air: list[tuple[float, int, int, bytes, int]] = []
        """Packets on their way from the nodes: (arrival, seq, node, reply, flags)."""
        self._jitter = {a: random.Random(self.rng.random()) for a in self.nodes}
        """A stream of random numbers per node: a node's delays are the same however
        the simulator's thread batches its work."""
        self._next_stall: float | None = None
        """When the output next stalls (drawn at the first packet: the clock's zero is
        arbitrary)."""

    # -- host side --------------------------------------------------------------------

    def from_host(self, data: bytes, now: float) -> None:
        for event in self._host.feed(data):
            self._handle(event, now)

    def host_idle(self, now: float) -> None:
        """The host stopped writing mid-packet: NACK what it left."""
        for event in self._host.line_idle():
            self._handle(event, now)

    def _handle(self, event: CommandPacket | PingRequest | Garbled, now: float) -> None:
        if not isinstance(event, Garbled):
            self.from_host_log.append((now, event))
        if isinstance(event, Garbled):
            self.stats.nacks += 1
            self._queue(bytes((NACK,)), now, control=True)
        elif isinstance(event, PingRequest):
            self.stats.pings += 1
            link = self.radio.get(event.node)
            ok = link is not None and link.in_range and self.nodes[event.node].powered
            delay = 2 * RADIO_LATENCY if ok else PING_TIMEOUT
            self._push_answer(now + delay, bytes((PING if ok else NACK,)))
        elif self.line.nack and self.rng.random() < self.line.nack:
            self.stats.nacks += 1
            self._queue(bytes((NACK,)), now, control=True)
        else:
            self.stats.acks += 1
            if self.line.glue_ack:
                if self._held_ack_since is None:
                    self._held_ack_since = now
                self._held_acks += 1
            else:
                self._queue(bytes((ACK,)), now, control=True)
            self._broadcast(event.node, event.command, now)

    def _broadcast(self, node: int, command: bytes, now: float) -> None:
        link = self.radio.get(node)
        loss = 0.0 if link is None else link.command_loss
        if link is not None and command[:1] == b"\xfa":
            loss = 1 - (1 - loss) * (1 - link.stop_loss)
        if (link is None or not link.in_range or not self.nodes[node].powered
                or self.rng.random() < loss):
            self.stats.commands_lost += 1
            return
        self._seq += 1
        heapq.heappush(self._to_nodes, (now + RADIO_LATENCY, self._seq, node, command))

    def _push_answer(self, due: float, byte: bytes) -> None:
        self._seq += 1
        heapq.heappush(self._answers, (due, self._seq, byte))

    # -- radio side -------------------------------------------------------------------

    def reboot(self, address: int, now: float) -> None:
        """The node lost power and came back: it announces itself with a discovery
        packet (delivery flags 0x00) and starts over."""
        # The announcement is one of the node's packets: it goes over the radio behind
        # those the node sent before it lost power, and a caller that is late (the
        # simulator's thread was not scheduled) first brings the station up to ``now``,
        # so what reached the base station before the reboot is on the line before it.
        # Put straight on the line, it overtook a record still in the air, whose timer
        # then read as the restarted one (issue 24: 0.4 s after a reboot, under load).
        # A node switched off stays off.
        if not self.nodes[address].powered:
            return
        self.advance(now)
        self.nodes[address].power_up(now)
        self._launch(address, now, b"\x01" + FIRMWARE_VERSION.to_bytes(4, "big"),
                     FLAGS_DISCOVERY)

    def power(self, address: int, on: bool, now: float) -> bool:
        """Switch a node on (it powers up, announcing itself with a discovery packet as
        after a reboot, and streams what it auto-starts) or off (from now it hears no
        command and sends nothing; what it sent before is still in the air). Whether
        that changed anything (False: it was so already)."""
        node = self.nodes[address]
        if node.powered == on:
            return False
        self.advance(now)
        node.powered = on
        if on:
            self.reboot(address, now)
        return True

    def advance(self, now: float) -> None:
        """Everything due by ``now``, in time order: commands reach nodes, nodes finish
        cycles, replies and answers reach the serial line. In order even when called
        late: a command reaches a node after the cycles before it, and an answer goes on
        the line behind the records that reached the base station first."""
        while True:
            heads = [queue[0][0] for queue in (self._answers, self._to_nodes) if queue]
            if not heads or min(heads) > now:
                break
            due = min(heads)
            self._replies_until(due)
            if self._answers and self._answers[0][0] == due:
                _, _, byte = heapq.heappop(self._answers)
                self._queue(byte, due, control=True)
            else:
                _, _, address, command = heapq.heappop(self._to_nodes)
                self.nodes[address].receive(command)
                self.stats.commands_delivered += 1
        self._replies_until(now)
        if self._held_ack_since is not None and now - self._held_ack_since >= GLUE_WAIT:
            self._queue(self._release_acks(), now, control=True)

    def _replies_until(self, t: float) -> None:
        """The replies that reach the base station by ``t``, in the order they arrive:
        each cycle's record is in the air from when it is made until its arrival."""
        for address, node in self.nodes.items():
            for c, reply in node.run_until(t - RADIO_LATENCY):
                self._launch(address, c, reply)
        while self._in_air and self._in_air[0][0] <= t:
            arrival, _, address, reply, flags = heapq.heappop(self._in_air)
            self._send_packet(address, reply, arrival, flags)

    def _launch(self, address: int, sent: float, reply: bytes, flags: int = FLAGS_REPLY) -> None:
        """A packet the node sends at ``sent`` takes to the air."""
        self._seq += 1  # (a node's packets keep the order it sent them in)
        heapq.heappush(self._in_air, (self._arrival(address, sent), self._seq, address,
                                      reply, flags))

    def _arrival(self, address: int, sent: float) -> float:
        """When a packet the node sent at ``sent`` reaches the base station: the radio's
        floor and a random part, never before the node's previous packet (a node's
        packets arrive in order)."""
        jitter = self.radio[address].jitter
        extra = min(self._jitter[address].expovariate(1 / jitter), JITTER_MAX) if jitter \
            else 0.0
        arrival = max(sent + RADIO_LATENCY + extra, self._arrived.get(address, 0.0))
        self._arrived[address] = arrival
        return arrival

    def _stall_after(self, t: float) -> float:
        rate = self.line.stall_rate
        return t + self.rng.expovariate(rate) if rate else float("inf")

    def _release_acks(self) -> bytes:
        acks = bytes((ACK,)) * self._held_acks
        self._held_ack_since, self._held_acks = None, 0
        return acks

    def _send_packet(self, address: int, reply: bytes, t: float,
                     flags: int = FLAGS_REPLY) -> None:
        link = self.radio[address]
        if not link.in_range or self.rng.random() < link.data_loss:
            self.stats.packets_lost_radio += 1
            return
        lqi = max(0, min(255, link.lqi + self.rng.randint(-3, 3)))
        rssi = max(-128, min(127, link.rssi + self.rng.randint(-2, 2)))
        packet = self._with_faults(encode_reply_packet(address, reply, lqi, rssi, flags))
        acks = self._release_acks() if self._held_acks else b""
        if self._queue(acks + packet, t):
            self.stats.packets_sent[address] = self.stats.packets_sent.get(address, 0) + 1
        else:
            self.stats.packets_dropped_full += 1
            if acks:
                self._queue(acks, t, control=True)

    def _with_faults(self, packet: bytes) -> bytes:
        line, rng = self.line, self.rng
        if line.bad_checksum and rng.random() < line.bad_checksum:
            self.stats.faults_injected += 1
            packet = packet[:-1] + bytes(((packet[-1] + 1 + rng.randrange(255)) & 0xFF,))
        if line.false_header and rng.random() < line.false_header:
            self.stats.faults_injected += 1
            packet = bytes((0xAA, rng.randrange(256), 0, 0, 0x4C, 0xFF)) + packet
        if line.garbage and rng.random() < line.garbage:
            self.stats.faults_injected += 1
            packet += bytes(rng.randrange(256) for _ in range(rng.randint(1, 12)))
        return packet

    # -- the serial line --------------------------------------------------------------

    def _queue(self, chunk: bytes, t: float, control: bool = False) -> bool:
        """Schedule ``chunk`` on the UART; False if the buffer is full (never for
        ``control`` bytes, the base station's own answers)."""
        if self._next_stall is None:
            self._next_stall = self._stall_after(t)
        while t >= self._next_stall:  # a stall: the output is held back, then sent
            stall = self._next_stall
            self._line_free_at = max(self._line_free_at, stall) + self.line.stall_ms / 1000
            self.stats.stalls += 1
            self._next_stall = self._stall_after(stall)
        # (the bytes queued: the line's time ahead, less the gaps between them)
        backlog = (self._line_free_at - t) / self.byte_time * self.line.throughput
        limit = self.line.buffer_bytes
        if limit is not None and backlog + len(chunk) > limit and not control:
            return False
        if t > self._line_free_at > 0.0:
            self.stats.line_idle += t - self._line_free_at
        start = max(t, self._line_free_at)
        written = start + len(chunk) * self.byte_time
        self._line_free_at = start + len(chunk) * self.byte_time / self.line.throughput
        self._out.append((written, chunk))
        return True

    @property
    def backlog(self) -> int:
        """Bytes queued on the UART, not yet sent."""
        return sum(len(chunk) for _, chunk in self._out)

    def lose_output(self, at: float) -> None:
        """Unplugged until ``at``: what its UART still had to send, and the ACKs it held
        back, went with the device's power; its line is free from then on."""
        self.take_output(at)
        self._out.clear()
        self._held_ack_since, self._held_acks = None, 0
        self._line_free_at = at

    def take_output(self, now: float) -> bytes:
        """The bytes whose last bit has left the UART by ``now``."""
        chunks = []
        while self._out and self._out[0][0] <= now:
            chunks.append(self._out.popleft()[1])
        data = b"".join(chunks)
        self.stats.bytes_sent += len(data)
        return data

    def next_due(self, now: float) -> float:
        """When something next needs doing (for the caller's sleep)."""
        times = [now + 1.0]
        if self._out:
            times.append(self._out[0][0])
        if self._answers:
            times.append(self._answers[0][0])
        if self._to_nodes:
            times.append(self._to_nodes[0][0])
        if self._held_ack_since is not None:
            times.append(self._held_ack_since + GLUE_WAIT)
        if self._in_air:
            times.append(self._in_air[0][0])
        for node in self.nodes.values():
            if node.busy:
                times.append(node.next_cycle_time() + RADIO_LATENCY)
        return min(times)
