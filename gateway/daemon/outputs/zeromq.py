"""The ZeroMQ PUB side: the output whose send is the message's publication.

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

from . import Message, Needs, Output

log = logging.getLogger("gx2.publish")
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


class Publisher(Output):
    """The PUB socket: each message sent as ``[topic, msgpack payload]``."""

    def __init__(self, context: zmq.Context, endpoint: str, high_water_mark: int,
                 server: curve.KeyPair | None = None) -> None:
        # a plain socket even on the loop's asyncio context: sends never block (NOBLOCK),
        # and the asyncio wrapper would cost a future per record
        self.socket = context.socket(zmq.PUB, socket_class=zmq.Socket)
        self.socket.setsockopt(zmq.SNDHWM, high_water_mark)
        if server is not None:
            curve.serve(self.socket, server)
        self.socket.bind(endpoint)
        self.endpoint = endpoint
        self._pack = msgpack.Packer().pack
        self._socket_send = compiled_send(self.socket)
        self.sent = 0
        self.failed = 0
        """Messages not published: refused by ZeroMQ or unpackable (of them)."""
        self.unpackable = 0
        """Messages msgpack could not pack (the first logged, the rest counted)."""

    def take(self, message: Message) -> None:
        self.send(message.topic, message.payload)

    def send(self, name: bytes, payload: dict[str, Any]) -> bool:
        """Send one message; False if ZeroMQ refused it (counted and logged, never
        raised): the fan-out's answer for the message (:class:`.Outputs`)."""
        # packed before the first frame goes: a payload msgpack cannot pack (an int
        # over 64 bits, say) raised between the two frames, and the topic frame, sent
        # with SNDMORE, was glued onto the next message's
        try:
            packed = self._pack(payload)
        except (TypeError, ValueError, OverflowError) as error:
            self.failed += 1
            if not self.unpackable:
                log.warning("publish on %s refused: msgpack cannot pack it (%s); "
                            "such messages are counted in publish_failures, not logged "
                            "again", name.decode(errors="replace"), error)
            self.unpackable += 1
            return False
        try:
            self._socket_send(name, _MORE)
            self._socket_send(packed, _LAST)
        except zmq.ZMQError as error:
            self.failed += 1
            log.warning("publish on %s failed: %s", name.decode(), error)
            return False
        self.sent += 1
        return True

    def close(self, seconds: float = 0.0) -> None:
        """Close, leaving what is queued ``seconds`` to reach its subscribers.

        The context's end (the gateway's last step) waits up to that long for them: a
        replay that exits publishes its last records just before, and a subscriber on a
        busy host read them after a fixed 200 ms had dropped them (CI: 304 of 2,600)."""
        self.socket.close(linger=max(0, int(seconds * 1000)))


def make(needs: Needs) -> Publisher:
    config = needs.config
    return Publisher(needs.context, config.publish.endpoint, config.publish.high_water_mark,
                     needs.server if config.curve and config.curve.publish else None)
