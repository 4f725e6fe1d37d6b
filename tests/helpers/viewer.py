"""An independent Foxglove WebSocket client, as a viewer (Foxglove's app) speaks to the
gateway's live view: written here from the protocol's description, not with the SDK
the gateway uses, so the two cannot agree by sharing a mistake.

The protocol: JSON text messages for control (the server's ``serverInfo``, then
``advertise`` of its channels, each with its topic, encoding and schema; the client's
``subscribe`` with ids of its own), and binary messages for data: opcode 0x01, the
subscription id (u32), the log time in ns (u64), all little-endian, then the message.
foxglove-sdk serves it under the WebSocket subprotocol ``foxglove.sdk.v1`` (it refuses
the older name, ``foxglove.websocket.v1``, with HTTP 400), which Foxglove's app offers.
"""

from __future__ import annotations

import contextlib
import json
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01
_HEADER = struct.Struct("<BIQ")


@dataclass
class Received:
    topic: str
    log_time: int
    """ns"""
    payload: dict[str, Any]


@dataclass
class Viewer:
    url: str
    reading_queue: int = 64
    """Messages the client library buffers before it stops reading the socket."""
    connection: ClientConnection = field(init=False)
    server: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Advertised channels by id."""
    messages: list[Received] = field(default_factory=list)
    _subscriptions: dict[int, int] = field(default_factory=dict)
    """Subscription id -> channel id."""
    _open: contextlib.ExitStack = field(init=False)

    def __post_init__(self) -> None:
        self._open = contextlib.ExitStack()
        self.connection = self._open.enter_context(connect(
            self.url, subprotocols=[SUBPROTOCOL], max_size=None,
            max_queue=self.reading_queue, open_timeout=10))

    def read(self, seconds: float) -> None:
        """Take what the server sends for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                message = self.connection.recv(timeout=left)
            except TimeoutError:
                return
            self._take(message)

    def until(self, condition: Any, seconds: float, what: str) -> None:
        deadline = time.monotonic() + seconds
        while not condition(self):
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {seconds} s waiting for {what}; "
                                     f"channels {self.topics()}, {len(self.messages)} "
                                     "messages")
            self.read(0.05)

    def topics(self) -> dict[str, int]:
        return {channel["topic"]: id_ for id_, channel in self.channels.items()}

    def subscribe(self, *channel_ids: int) -> None:
        subscriptions = []
        for channel_id in channel_ids:
            subscription = len(self._subscriptions) + 1
            self._subscriptions[subscription] = channel_id
            subscriptions.append({"id": subscription, "channelId": channel_id})
        self.connection.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def close(self) -> None:
        """The closing handshake, reading (and dropping) what the server still sends
        meanwhile: a client whose queue is full reads nothing more off its socket, the
        server's close frame included, and would wait out its close timeout (10 s)."""
        closing = threading.Thread(target=self._open.close, daemon=True)
        closing.start()
        while closing.is_alive():
            try:
                self.connection.recv(timeout=0.05)
            except TimeoutError:
                continue
            except (ConnectionClosed, RuntimeError):  # (closed; or recv racing the close)
                break
        closing.join()

    def _take(self, message: str | bytes) -> None:
        if isinstance(message, str):
            control = json.loads(message)
            if control["op"] == "serverInfo":
                self.server = control
            elif control["op"] == "advertise":
                for channel in control["channels"]:
                    self.channels[channel["id"]] = channel
            elif control["op"] == "unadvertise":
                for channel_id in control["channelIds"]:
                    self.channels.pop(channel_id, None)
            return
        opcode, subscription, log_time = _HEADER.unpack_from(message)
        assert opcode == MESSAGE_DATA, f"binary opcode {opcode}"
        channel = self.channels[self._subscriptions[subscription]]
        self.messages.append(Received(channel["topic"], log_time,
                                      json.loads(message[_HEADER.size:])))
