"""The ZeroMQ PUB side: the one place a message is published.

Each message is ``[topic, msgpack payload]`` (topics: :mod:`gateway.common.topics`).
Sends never block: PUB drops for a subscriber past its high-water mark rather than
stall the serial reader.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import msgpack
import zmq

from gateway.common import curve
from gateway.common.topics import MARK_TOPIC, STATUS_TOPIC, parse, topic

log = logging.getLogger("gx2.publish")
Sink = Callable[[bytes, dict[str, Any]], None]
"""What is given every message published: its topic and its payload."""
_MORE, _LAST = int(zmq.SNDMORE | zmq.NOBLOCK), int(zmq.NOBLOCK)


def compiled_send(socket: zmq.Socket) -> Callable[[bytes, int], Any]:
    """The socket's send without pyzmq's Python-level wrapper, where pyzmq has one.

    The wrapper only adds the DRAFT routing_id/group options; skipping it makes a send
    2.0x faster (0.26 against 0.53 us, bench/micro.py), about 0.5 us a record for its
    two frames. A pyzmq whose backend lacks it (its CFFI build) gets the plain send."""
    backend = getattr(getattr(zmq, "backend", None), "Socket", None)
    send = getattr(backend, "send", None)
    if backend is not None and send is not None and isinstance(socket, backend):
        return send.__get__(socket)  # type: ignore[no-any-return]
    return socket.send  # type: ignore[return-value]


class Publisher:
    def __init__(self, context: zmq.Context, endpoint: str, high_water_mark: int,
                 server: curve.KeyPair | None = None) -> None:
        # a plain socket even on the loop's asyncio context: sends never block (NOBLOCK),
        # and the asyncio wrapper would cost a future per record
        self.socket = context.socket(zmq.PUB, socket_class=zmq.Socket)
        self.socket.setsockopt(zmq.SNDHWM, high_water_mark)
        self.socket.setsockopt(zmq.LINGER, 200)
        if server is not None:
            curve.serve(self.socket, server)
        self.socket.bind(endpoint)
        self.endpoint = endpoint
        self._topics: dict[tuple[int, str], list[Any]] = {}
        """(node, record) -> [its topic, messages published on it]."""
        self._pack = msgpack.Packer().pack
        self._socket_send = compiled_send(self.socket)
        self.sent = 0
        self.failed = 0
        self.record: Sink | None = None
        """Given every message published, when the gateway records or serves the live
        view (app.py's fan_out)."""

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        """Publish one record; False if ZeroMQ refused it (counted, never raised). A
        subscriber past its high-water mark loses messages silently inside PUB: it sees
        them as gaps in ``seq``."""
        key = (node, record)
        entry = self._topics.get(key)
        if entry is None:
            entry = self._topics[key] = [topic(node, record), 0]
        if self._send(entry[0], payload):
            entry[1] += 1
            return True
        return False

    def published(self) -> dict[int, dict[str, int]]:
        """Messages published on each topic: node -> record name -> count."""
        counts: dict[int, dict[str, int]] = {}
        for (node, record), (_, count) in self._topics.items():
            if count:
                counts.setdefault(node, {})[record] = count
        return counts

    def status(self, payload: dict[str, Any]) -> bool:
        return self._send(STATUS_TOPIC, payload)

    def mark(self, payload: dict[str, Any]) -> bool:
        return self._send(MARK_TOPIC, payload)

    def replayed(self, name: str, payload: dict[str, Any]) -> bool:
        """A message of a recording, published again on its topic as it was recorded (a
        node's record counted as one published on that node's topic)."""
        found = parse(name)
        if found is not None:
            return self.publish(*found, payload)
        return self._send(name.encode(), payload)

    def _send(self, name: bytes, payload: dict[str, Any]) -> bool:
        if self.record is not None:
            self.record(name, payload)
        try:
            self._socket_send(name, _MORE)
            self._socket_send(self._pack(payload), _LAST)
        except zmq.ZMQError as error:
            self.failed += 1
            log.warning("publish on %s failed: %s", name.decode(), error)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        self.socket.close()
