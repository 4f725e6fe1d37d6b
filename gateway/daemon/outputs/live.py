"""The live view: a Foxglove WebSocket server (``live:``), so that Foxglove shows the
signals as they come, and each node's orientation in its 3D panel.

It is foxglove-sdk's server (a Rust core, in threads of its own), given every message
the gateway publishes: a channel per topic as it first appears (a node's records, the
status, the marks; a node's frame, ``gx2/<address>/frame``, Foxglove's own
``foxglove.FrameTransform``: :mod:`.frames`), JSON with the recording's schema
(gateway.common.schemas, where the frame's is Foxglove's JSON Schema of it), each
message at its sample's instant (recording/files.py, ``message_times``). Nothing on
the loop waits for a viewer: the SDK keeps a queue per viewer (``backlog`` messages)
and drops the oldest for one that reads slowly, and a channel no viewer subscribes to
costs one call into the SDK and no JSON. Read-only: the server advertises no
capability (no client publishing, parameters or services), so nothing a viewer sends
reaches a node.

Imported only when ``live:`` is configured, as metrics.py is.
"""

from __future__ import annotations

import logging
import re
import threading
from pathlib import Path
from typing import Any

import foxglove
from foxglove import Channel, Schema

from gateway.common.endpoints import host_port, is_loopback
from gateway.common.jsontext import compact
from gateway.common.schemas import ENCODING as SCHEMA_ENCODING
from gateway.common.schemas import schema_for_topic
from gateway.recording.files import JSON_ENCODING, OutOfRange, message_times, ns

from ..config import LiveConfig
from ..errors import StartupError
from . import Message, Needs, Output

log = logging.getLogger("gx2.live")
STOP_WAIT = 0.5
"""Seconds a shutdown waits at most for the server to stop: with viewers connected
(reading or not) the SDK's ``stop()`` took 0.2 ms here; what outlasts this waits on a
connection that says nothing (:meth:`LiveServer.close`)."""


BIND_FAILED = re.compile(r"Failed to bind port: (?P<why>.*?)(?: \(os error (?P<errno>\d+)\))?$")
"""How the SDK says it could not bind (``FoxgloveError: Failed to bind port: Address
already in use (os error 98)``), apart from its other errors (``Configuration error:
TLS configuration: ...``)."""


def _tls(config: LiveConfig) -> dict[str, bytes]:
    """The SDK's TLS arguments: none, or the certificate's and key's bytes."""
    if config.tls_cert is None or config.tls_key is None:
        return {}
    return {"tls_cert": Path(config.tls_cert).read_bytes(),
            "tls_key": Path(config.tls_key).read_bytes()}


def tls_refusal(config: LiveConfig) -> str | None:
    """Why the SDK would not serve with ``config``'s certificate and key (None if it
    would, or there are none), found by starting it on a free loopback port and
    stopping it at once: what rustls refuses although OpenSSL (tls.py) took it, such as
    a DSA or Ed448 key. For ``--check``; nothing is left running."""
    tls = _tls(config)
    if not tls:
        return None
    try:
        foxglove.start_server(name="gx2-gateway --check", host="127.0.0.1", port=0,
                              capabilities=[], context=foxglove.Context(), **tls).stop()
    except RuntimeError as error:
        if BIND_FAILED.search(str(error)):
            return None  # (no loopback to try it on: the start will tell)
        return str(error).removeprefix("FoxgloveError: ")
    return None


def refusal(endpoint: str, text: str) -> OSError | StartupError:
    """The SDK's refusal to start, as the gateway says it: OSError for the port (the
    gateway's "cannot bind"), StartupError in the SDK's words for anything else (a
    certificate it could not use is no port in use)."""
    bind = BIND_FAILED.search(text)
    if bind is not None:
        return OSError(int(bind["errno"] or 0), bind["why"])
    return StartupError(f"live view on {endpoint}: {text.removeprefix('FoxgloveError: ')}")


class Viewers(foxglove.ServerListener):
    """Who is watching: the viewers subscribed to at least one channel, and their
    subscriptions (called from the SDK's threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribed: dict[int, set[int]] = {}
        self.subscriptions = 0
        """Subscriptions made since start, every viewer's."""

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            self._subscribed.setdefault(client.id, set()).add(channel.id)
            self.subscriptions += 1

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            channels = self._subscribed.get(client.id, set())
            channels.discard(channel.id)
            if not channels:
                self._subscribed.pop(client.id, None)

    def status(self) -> dict[str, int]:
        with self._lock:
            return {"viewers": len(self._subscribed),
                    "subscribed": sum(len(c) for c in self._subscribed.values()),
                    "subscriptions": self.subscriptions}


class LiveServer(Output):
    """The server and its channels. :meth:`take` is given every message the
    gateway publishes, on the loop."""

    def __init__(self, config: LiveConfig) -> None:
        host, port = host_port(config.endpoint)
        self.endpoint = config.endpoint
        self.viewers = Viewers()
        self._context = foxglove.Context()
        tls = _tls(config)
        try:
            self._server = foxglove.start_server(
                name="gx2-gateway", host=host.strip("[]"), port=port, capabilities=[],
                server_listener=self.viewers, context=self._context,
                message_backlog_size=config.backlog, **tls)
        except RuntimeError as error:
            raise refusal(config.endpoint, str(error)) from None
        self.url = f"{'wss' if tls else 'ws'}://{config.endpoint}"
        self.messages = 0
        """Messages given to a channel some viewer subscribed to."""
        self.refused = 0
        """Messages no viewer could be given: a time no message time holds (a foreign
        recording's ``time`` in nanoseconds, replayed), each said once a topic."""
        self._refused_topics: set[bytes] = set()
        self._channels: dict[bytes, Channel | None] = {}
        if not is_loopback(f"tcp://{host}:{port}"):
            log.warning("live view on %s: any host that reaches it may watch (it is "
                        "read-only and unauthenticated)", config.endpoint)

    def take(self, message: Message) -> None:
        """A published message, to the viewers of its topic (if any)."""
        topic = message.topic
        channel = self._channels.get(topic, False)
        if channel is False:
            channel = self._channels[topic] = self._open(topic)
        if channel is None or not channel.has_sinks():
            return
        try:
            log_time = ns((message.times or message_times(message.payload))[1])
        except OutOfRange as error:  # (raised here, on the loop, it would end the replay)
            self._refuse(topic, error)
            return
        channel.log(message.json(), log_time=log_time)
        self.messages += 1

    def _refuse(self, topic: bytes, error: OutOfRange) -> None:
        self.refused += 1
        if topic not in self._refused_topics:
            self._refused_topics.add(topic)
            log.warning("live view: a message of %s not shown: %s (counted in status "
                        "live.refused; said once a topic)", topic.decode(), error)

    def _open(self, topic: bytes) -> Channel | None:
        """The channel of a topic the gateway publishes, with its schema (None for one
        without a schema: nothing the gateway publishes, but a replay may hold more)."""
        name = topic.decode()
        described = schema_for_topic(name)
        if described is None:
            return None
        schema_name, schema = described
        return Channel(name, schema=Schema(name=schema_name, encoding=SCHEMA_ENCODING,
                                           data=compact(schema).encode()),
                       message_encoding=JSON_ENCODING, context=self._context)

    def status(self) -> dict[str, Any]:
        return {"endpoint": self.endpoint, "url": self.url,
                "channels": sum(1 for c in self._channels.values() if c is not None),
                "messages": self.messages, "refused": self.refused,
                **self.viewers.status()}

    def close(self, seconds: float) -> None:
        """Stop serving, waiting for it ``seconds`` at most (and STOP_WAIT).

        The SDK's ``stop()`` waits for every connection to end, and a connection that
        never completes its WebSocket handshake (a client that connects and says
        nothing) is never ended by the server: a bare ``stop()`` waited 48 s, until the
        client left, and the gateway's exit with it. So it runs in a daemon thread that
        is waited for a while (it takes well under a millisecond when every connection
        is a viewer), then left: blocked in the SDK, it ends with the process, as the
        SDK's own runtime threads do (a daemon thread is not joined at exit, and the
        runtime's threads are no Python threads; the process exited 0 at once so in
        tests/e2e/test_live.py)."""
        stopping = threading.Thread(target=self._server.stop, name="gx2-live-stop",
                                    daemon=True)
        stopping.start()
        stopping.join(max(0.0, min(seconds, STOP_WAIT)))
        if stopping.is_alive():
            log.warning("live view: a connection that never completed its WebSocket "
                        "handshake is still open: left to the process's exit")


def make(needs: Needs) -> LiveServer:
    assert needs.config.live is not None
    return LiveServer(needs.config.live)
