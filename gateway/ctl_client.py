"""gx2ctl's side of the control protocol (:mod:`gateway.protocol`): one DEALER, requests
with an id, a deadline that is never overrun, one safe retry, and exit statuses.
"""

from __future__ import annotations

import contextlib
import math
import time
import uuid
from dataclasses import dataclass
from typing import Any

import msgpack
import zmq

from . import curve

MAX_REPLY_BYTES = 1 << 20
"""gateway.protocol.MAX_REPLY_BYTES (not imported: gateway.protocol loads pydantic, which
would slow every run; a test checks that the two agree)."""
OK, NODE_FAILED, USAGE, NO_ANSWER = 0, 1, 2, 3
ERROR_STATUS = {"invalid": USAGE, "refused": NODE_FAILED, "node": NODE_FAILED,
                "link": NODE_FAILED, "internal": NODE_FAILED}
"""Exit status for each error kind of the protocol; an unknown kind gives 1."""


class CtlError(Exception):
    """Ends the run: a one-line message and the exit status it gives."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(" ".join(message.split()) or "failed")
        self.status = status


WILDCARD_HOSTS = ("*", "0.0.0.0", "::", "[::]", "[*]")


def tcp_host(address: str) -> str | None:
    scheme, _, rest = address.partition("://")
    return rest.rpartition(":")[0] if scheme == "tcp" else None


def connectable(address: str, near: str) -> str:
    """A bind address (``tcp://*:5555``) turned into one to connect to: the host of
    ``near`` (the control endpoint) if that is concrete, else the loopback."""
    host = tcp_host(address)
    if host not in WILDCARD_HOSTS:
        return address
    other = tcp_host(near)
    concrete = other if other and other not in WILDCARD_HOSTS else "127.0.0.1"
    return f"tcp://{concrete}:{address.rpartition(':')[2]}"


@dataclass(frozen=True)
class ClientKeys:
    """CURVE: this client's pair and the gateway's public key."""

    client: curve.KeyPair
    server_public: bytes


class Client:
    """Requests over one DEALER; a request lost on the way is sent once more, with the
    same id, at half the timeout (the gateway answers a repeated id from its memory)."""

    def __init__(self, control: str, timeout: float, keys: ClientKeys | None = None) -> None:
        self.control = connectable(control, control)
        self.timeout = timeout
        self.context = zmq.Context()
        self.socket = self.context.socket(zmq.DEALER)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)
        self.secured = keys is not None
        if keys is not None:
            curve.connect_as(self.socket, keys.client, keys.server_public)
        # The gateway remembers requests by (client identity, id): a fixed identity keeps
        # a retry sent over a new connection (after a network blip) the same request.
        self.socket.setsockopt(zmq.ROUTING_ID, b"gx2ctl-" + uuid.uuid4().hex.encode())
        try:
            self.socket.connect(self.control)
        except zmq.ZMQError as error:
            self.close()
            raise CtlError(f"cannot use control endpoint {self.control}: {error}",
                           USAGE) from None

    def close(self) -> None:
        self.socket.close(linger=0)
        self.context.term()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, op: str, **fields: Any) -> dict[str, Any]:
        """The ``result`` of one request; CtlError for an error reply or no reply."""
        request_id = uuid.uuid4().hex
        payload = msgpack.packb({"id": request_id, "op": op, **fields})
        start = time.monotonic()
        deadline, resend_at = start + self.timeout, start + self.timeout / 2
        self._send(payload)
        while (left := deadline - time.monotonic()) > 0:
            if resend_at and time.monotonic() >= resend_at:
                self._send(payload)  # identical, same id: safe even if the first arrived
                resend_at = 0.0
            wait = min(left, resend_at - time.monotonic()) if resend_at else left
            if self.socket.poll(max(0, math.ceil(wait * 1000)), zmq.POLLIN):
                reply = self._receive()
                if reply is not None and reply.get("id") == request_id:
                    return _result(reply)
        raise CtlError(f"no answer from the gateway at {self.control} within "
                       f"{self.timeout:g} s (is gx2-gateway running"
                       f"{', and is this key allowed' if self.secured else ''}?)", NO_ANSWER)

    def _send(self, payload: bytes) -> None:
        with contextlib.suppress(zmq.Again):  # nowhere to send yet: the deadline decides
            self.socket.send_multipart([b"", payload], flags=zmq.NOBLOCK)

    def _receive(self) -> dict[str, Any] | None:
        """The reply map, or None for anything else (skipped: it cannot be ours)."""
        try:
            frames = self.socket.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return None
        if len(frames) == 2 and frames[0] == b"":
            frames = frames[1:]
        if len(frames) != 1:
            return None
        try:
            reply = msgpack.unpackb(frames[0], raw=False, strict_map_key=False)
        except Exception:  # msgpack raises several unrelated types
            return None
        return reply if isinstance(reply, dict) else None


def _result(reply: dict[str, Any]) -> dict[str, Any]:
    """The result of a reply to our request, or CtlError with the gateway's message."""
    if reply.get("ok") is True and isinstance(reply.get("result"), dict):
        return reply["result"]
    error = reply.get("error")
    if reply.get("ok") is not False or not isinstance(error, dict):
        raise CtlError("the gateway sent a malformed reply", NODE_FAILED)
    kind, message = error.get("kind"), error.get("message")
    text = message if isinstance(message, str) and message.strip() else f"{kind} error"
    raise CtlError(text, ERROR_STATUS.get(kind, NODE_FAILED) if isinstance(kind, str)
                   else NODE_FAILED)
