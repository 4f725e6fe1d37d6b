"""Subscribing to gx2-gateway from Python: the records of chosen nodes, from one gateway
or several, with their losses counted.

    from gateway.client import Subscriber

    with Subscriber("tcp://127.0.0.1:5555", nodes=[76], records=["accel_angrate"]) as sub:
        for message in sub:
            print(message.node, message.time, message["accel"], message.gap)

Each gateway numbers every node's messages (``seq``, +1 per message), so a gap is
messages that never reached this subscriber (over ZeroMQ, or on a slow subscriber
past its high-water mark); records the node never sent are in the gateway's status
instead. Node filters subscribe to the node's whole topic, and records are filtered
here, so a record of another kind (a poll) is never mistaken for a gap. A ``seq``
that goes back means the gateway restarted. NaN (a magnetometer the node lacks)
stays NaN; :meth:`Message.json` turns it into null.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import msgpack
import zmq

from gateway.common import curve
from gateway.common.jsontext import json_line
from gateway.common.protocol import MAX_REPLY_BYTES
from gateway.common.topics import PREFIX, STATUS_TOPIC, node_prefix, parse

__all__ = ["GatewayError", "Malformed", "Message", "Status", "Subscriber"]
log = logging.getLogger("gx2.client")
BOOKKEEPING = frozenset(("node", "record", "command", "seq", "host_time", "time",
                         "device_time", "lqi", "rssi"))
"""Keys every record carries besides its own fields."""


class GatewayError(Exception):
    """The subscriber cannot be set up (a bad endpoint or key): one line."""


class Malformed(Exception):
    """A message that is not ``[topic, msgpack map]`` of the gateway's shape."""


@dataclass(frozen=True, slots=True)
class Message:
    """One record of one node, as its gateway published it."""

    gateway: str
    """The endpoint it came from."""
    node: int
    record: str
    seq: int
    host_time: float
    time: float | None
    """When the node took the sample (UNIX s, host clock); None for an untimed record."""
    device_time: float | None
    lqi: int | None
    rssi: int | None
    payload: Mapping[str, Any] = field(repr=False)
    """Everything published, the record's own fields and the keys above."""
    gap: int = 0
    """Messages of this node that did not reach this subscriber just before this one."""
    restarted: bool = False
    """The first message after the gateway restarted (its ``seq`` began again)."""

    def __getitem__(self, name: str) -> Any:
        return self.payload[name]

    def __contains__(self, name: object) -> bool:
        return name in self.payload

    @property
    def fields(self) -> dict[str, Any]:
        """The record's own fields (``accel``, ``timer``, ...)."""
        return {k: v for k, v in self.payload.items() if k not in BOOKKEEPING}

    def json(self) -> str:
        """The payload as one strict JSON line (NaN as null)."""
        return json_line(self.payload)


@dataclass(frozen=True, slots=True)
class Status:
    """The gateway's heartbeat (``gx2/gateway/status``): the map ``gx2ctl status`` shows."""

    gateway: str
    payload: Mapping[str, Any] = field(repr=False)
    restarted: bool = False
    """The gateway started again since its last status."""

    @property
    def nodes(self) -> list[dict[str, Any]]:
        nodes = self.payload.get("nodes")
        return [n for n in nodes if isinstance(n, dict)] if isinstance(nodes, list) else []


Event = Message | Status


class Subscriber:
    """Records from one or more gateways' publish endpoints.

    ``nodes``/``records`` filter (empty: all); ``status=True`` also yields each
    gateway's heartbeat, and ``status="only"`` nothing else (a monitor: no record
    crosses the network to it). ``keys``: CURVE keys, when the gateway encrypts its stream
    (:func:`gateway.common.curve.load_client_keys`). Malformed messages are
    skipped, counted in ``malformed`` and given to ``on_malformed`` (default: logged).
    """

    def __init__(self, endpoints: str | Iterable[str], nodes: Iterable[int] = (),
                 records: Iterable[str] = (), *, status: bool | Literal["only"] = False,
                 keys: curve.ClientKeys | None = None,
                 on_malformed: Callable[[str, Malformed], None] | None = None,
                 context: zmq.Context | None = None) -> None:
        self.endpoints = [endpoints] if isinstance(endpoints, str) else list(endpoints)
        if not self.endpoints:
            raise GatewayError("no publish endpoint to subscribe to")
        self.nodes = frozenset(nodes)
        self.records = frozenset(records)
        if status not in (False, True, "only"):
            raise ValueError(f"status must be True, False or 'only', not {status!r}")
        self.yield_status = bool(status)
        self.only_status = status == "only"
        self.on_malformed = on_malformed or _log_malformed
        self._own_context = context is None
        self.context = context or zmq.Context()
        self._sockets: dict[zmq.Socket, str] = {}
        self._order: list[zmq.Socket] = []
        self._next = 0
        """Where the next take starts in ``_order``: the socket after the last one taken from."""
        self._poller = zmq.Poller()
        self._last_seq: dict[tuple[str, int], int] = {}
        self._uptime: dict[str, float] = {}
        self.lost: dict[tuple[str, int], int] = {}
        """Per (gateway, node): messages that never reached this subscriber."""
        self.restarts: dict[str, int] = dict.fromkeys(self.endpoints, 0)
        self.heard: dict[str, float] = {}
        """Per gateway: when it last published anything (``time.monotonic()``)."""
        self._created = time.monotonic()
        self.malformed = 0
        try:
            for endpoint in self.endpoints:
                self._connect(endpoint, keys)
        except BaseException:
            self.close()
            raise

    def _connect(self, endpoint: str, keys: curve.ClientKeys | None) -> None:
        socket = self.context.socket(zmq.SUB)
        self._sockets[socket] = endpoint
        self._order.append(socket)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)  # records are far smaller
        if keys is not None:
            curve.connect_as(socket, keys)
        try:
            socket.connect(endpoint)
        except zmq.ZMQError as error:
            raise GatewayError(f"cannot subscribe to {endpoint}: {error}") from None
        prefixes = [node_prefix(node) for node in sorted(self.nodes)] or [PREFIX]
        for prefix in () if self.only_status else prefixes:
            socket.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        socket.setsockopt(zmq.SUBSCRIBE, STATUS_TOPIC)  # (heard from, restarts)
        self._poller.register(socket, zmq.POLLIN)

    # -- receiving ----------------------------------------------------------------------------

    def receive(self, timeout: float | None = None) -> Event | None:
        """The next message, or None after ``timeout`` seconds (None: wait for ever).

        Gateways are read in turn: while several have messages queued, each gives one."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            event = self._take_in_turn()
            if event is not None:
                return event
            wait = None if deadline is None else deadline - time.monotonic()
            if wait is not None and wait <= 0:
                return None
            self._poller.poll(None if wait is None else max(1, math.ceil(wait * 1000)))

    def __iter__(self) -> Iterator[Event]:
        while True:
            event = self.receive()
            if event is not None:
                yield event

    # Starting every take at the first socket starves the others while it has anything
    # queued: two gateways at 300 msg/s and a reader of 250 msg/s got {76: 1439, 77: 0} in
    # 6 s, and silent_for() of the second grew as if it were dead (issue 19). So each take
    # starts at the socket after the one the last message came from (round robin).
    def _take_in_turn(self) -> Event | None:
        """The next wanted message queued on any socket, the sockets taken in turn."""
        order = self._order
        count = len(order)
        for step in range(count):
            index = (self._next + step) % count
            event = self._take(order[index])
            if event is not None:
                self._next = (index + 1) % count
                return event
        return None

    def _take(self, socket: zmq.Socket) -> Event | None:
        """The first wanted message already queued on ``socket``, or None."""
        endpoint = self._sockets[socket]
        while True:
            try:
                frames = socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return None
            self.heard[endpoint] = time.monotonic()
            try:
                event = self._parse(endpoint, frames)
            except Malformed as problem:
                self.malformed += 1
                self.on_malformed(endpoint, problem)
                continue
            if event is not None:
                return event

    def _parse(self, endpoint: str, frames: list[bytes]) -> Event | None:
        topic = frames[0].decode("ascii", "replace") if frames else ""
        if len(frames) != 2:
            raise Malformed(f"on {topic or '(no topic)'}: {len(frames)} frames, not 2")
        try:
            payload = msgpack.unpackb(frames[1], raw=False, strict_map_key=False)
        except Exception:  # msgpack raises several unrelated types
            raise Malformed(f"on {topic}: the payload is not msgpack") from None
        if not isinstance(payload, dict):
            raise Malformed(f"on {topic}: the payload is a {type(payload).__name__}, "
                            "not a map")
        if frames[0] == STATUS_TOPIC:
            status = Status(endpoint, payload, self._gateway_started(endpoint, payload))
            return status if self.yield_status else None
        where = parse(topic)
        if where is None:
            return None  # another topic under gx2/: not a record
        node, record = where
        seq = payload.get("seq")
        if not isinstance(seq, int) or isinstance(seq, bool):
            raise Malformed(f"on {topic}: no integer seq")
        gap, restarted = self._count(endpoint, node, seq)
        if (self.nodes and node not in self.nodes) or (self.records
                                                       and record not in self.records):
            return None
        return Message(endpoint, node, record, seq, _number(payload.get("host_time")) or 0.0,
                       _number(payload.get("time")), _number(payload.get("device_time")),
                       _integer(payload.get("lqi")), _integer(payload.get("rssi")),
                       payload, gap, restarted)

    def _count(self, endpoint: str, node: int, seq: int) -> tuple[int, bool]:
        key = (endpoint, node)
        last = self._last_seq.get(key)
        self._last_seq[key] = seq
        if last is None:
            return 0, False
        if seq <= last:  # the gateway's numbering began again
            return 0, True
        gap = seq - last - 1
        if gap:
            self.lost[key] = self.lost.get(key, 0) + gap
        return gap, False

    def _gateway_started(self, endpoint: str, payload: Mapping[str, Any]) -> bool:
        """Whether this status is the first since the gateway started again: its uptime
        went back (a step of the host clock moves neither)."""
        gateway = payload.get("gateway")
        uptime = _number(gateway.get("uptime")) if isinstance(gateway, dict) else None
        if uptime is None:
            return False
        before = self._uptime.get(endpoint)
        self._uptime[endpoint] = uptime
        if before is not None and uptime < before:
            self.restarts[endpoint] += 1
            return True
        return False

    def silent_for(self, endpoint: str | None = None) -> float:
        """Seconds since ``endpoint`` (default: the first) last published anything, or
        since this subscriber was made if it never has."""
        return time.monotonic() - self.heard.get(endpoint or self.endpoints[0], self._created)

    # -- life ---------------------------------------------------------------------------------

    def close(self) -> None:
        for socket in self._sockets:
            socket.close(linger=0)
        self._sockets.clear()
        self._order.clear()
        if self._own_context:
            self.context.term()

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(
        value, bool) else None


def _integer(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _log_malformed(endpoint: str, problem: Malformed) -> None:
    log.warning("%s: skipped a message %s", endpoint, problem)
