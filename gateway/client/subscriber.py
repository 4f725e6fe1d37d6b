"""The live subscriber: records from one or more gateways' publish endpoints.

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
from typing import Literal

import msgpack
import zmq

from gateway.common import curve
from gateway.common.protocol import MAX_REPLY_BYTES
from gateway.common.topics import PREFIX, STATUS_TOPIC, node_prefix, parse

from .messages import Event, Malformed, Numbering, Status

log = logging.getLogger("gx2.client")


class GatewayError(Exception):
    """The subscriber cannot be set up (a bad endpoint or key): one line."""


class Subscriber:
    """Records from one or more gateways' publish endpoints.

    ``nodes``/``records`` filter (empty: all); ``status=True`` also yields each
    gateway's heartbeat, and ``status="only"`` nothing else (a monitor: no record
    crosses the network to it). ``keys``: CURVE keys, when the gateway encrypts its stream
    (:func:`gateway.common.curve.load_client_keys`): one set for every endpoint, or a
    map endpoint -> keys (None, or an endpoint missing from it: plain), for gateways
    with server keys of their own. Malformed messages are
    skipped, counted in ``malformed`` and given to ``on_malformed`` (default: logged).
    """

    def __init__(self, endpoints: str | Iterable[str], nodes: Iterable[int] = (),
                 records: Iterable[str] = (), *, status: bool | Literal["only"] = False,
                 keys: curve.ClientKeys | Mapping[str, curve.ClientKeys | None] | None = None,
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
        self._numbering = Numbering()
        self.lost = self._numbering.lost
        """Per (gateway, node): messages that never reached this subscriber."""
        self.restarts = self._numbering.restarts
        self.restarts.update(dict.fromkeys(self.endpoints, 0))
        self.heard: dict[str, float] = {}
        """Per gateway: when it last published anything (``time.monotonic()``)."""
        self._created = time.monotonic()
        self._added: dict[str, float] = {}
        """Per gateway added after the others (:meth:`add`): when."""
        self.malformed = 0
        try:
            for endpoint in self.endpoints:
                self._connect(endpoint, keys.get(endpoint) if isinstance(keys, Mapping)
                              else keys)
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
            del self._sockets[socket]
            self._order.remove(socket)
            socket.close(linger=0)
            raise GatewayError(f"cannot subscribe to {endpoint}: {error}") from None
        prefixes = [node_prefix(node) for node in sorted(self.nodes)] or [PREFIX]
        for prefix in () if self.only_status else prefixes:
            socket.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        socket.setsockopt(zmq.SUBSCRIBE, STATUS_TOPIC)  # (heard from, restarts)
        self._poller.register(socket, zmq.POLLIN)

    def add(self, endpoint: str, keys: curve.ClientKeys | None = None) -> None:
        """Subscribe to one more gateway's publish endpoint, as those given when it
        was made (``keys``: its CURVE keys, None: plain); GatewayError for a bad
        endpoint or key, and nothing added. A gateway found after the others is
        subscribed to when found: its silence counts from then."""
        if endpoint in self.endpoints:
            return
        self._connect(endpoint, keys)
        self.endpoints.append(endpoint)
        self.restarts.setdefault(endpoint, 0)
        self._added[endpoint] = time.monotonic()

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
            status = Status(endpoint, payload, self._numbering.started(endpoint, payload))
            return status if self.yield_status else None
        where = parse(topic)
        if where is None:
            return None  # another topic under gx2/: not a record
        node, record = where
        wanted = (not self.nodes or node in self.nodes) and (
            not self.records or record in self.records)
        return self._numbering.message(endpoint, node, record, payload, topic, wanted)

    def silent_for(self, endpoint: str | None = None) -> float:
        """Seconds since ``endpoint`` (default: the first) last published anything, or
        since it was subscribed to if it never has."""
        endpoint = endpoint or self.endpoints[0]
        return time.monotonic() - self.heard.get(
            endpoint, self._added.get(endpoint, self._created))

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


def _log_malformed(endpoint: str, problem: Malformed) -> None:
    log.warning("%s: skipped a message %s", endpoint, problem)
