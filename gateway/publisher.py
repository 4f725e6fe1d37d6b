"""The ZeroMQ PUB side: the one place a message is published.

Each message is ``[topic, msgpack payload]`` with topic ``gx2/<address>/<record>``
(decimal, no padding; a subscriber to ``gx2/76/`` gets node 76 and never node 760).
The gateway's own status goes on ``gx2/gateway/status``, which no node topic can equal.
Sends never block: PUB drops for a subscriber past its high-water mark rather than
stall the serial reader.
"""

from __future__ import annotations

import logging
from typing import Any

import msgpack
import zmq
import zmq.backend

from . import curve

log = logging.getLogger("gx2.publish")
STATUS_TOPIC = b"gx2/gateway/status"
_MORE, _LAST = int(zmq.SNDMORE | zmq.NOBLOCK), int(zmq.NOBLOCK)


def topic(node: int, record: str) -> bytes:
    return f"gx2/{node}/{record}".encode("ascii")


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
        self._topics: dict[tuple[int, str], bytes] = {}
        self._pack = msgpack.Packer().pack
        # the compiled send itself: pyzmq's Python-level wrapper only adds the DRAFT
        # routing_id/group options, and costs a third of each call
        self._socket_send = zmq.backend.Socket.send.__get__(self.socket)
        self.sent = 0
        self.failed = 0

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        """Publish one record; False if ZeroMQ refused it (counted, never raised). A
        subscriber past its high-water mark loses messages silently inside PUB: it sees
        them as gaps in ``seq``."""
        key = (node, record)
        name = self._topics.get(key)
        if name is None:
            name = self._topics[key] = topic(node, record)
        return self._send(name, payload)

    def status(self, payload: dict[str, Any]) -> bool:
        return self._send(STATUS_TOPIC, payload)

    def _send(self, name: bytes, payload: dict[str, Any]) -> bool:
        try:  # two plain sends: send_multipart's per-frame flag arithmetic costs more
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
