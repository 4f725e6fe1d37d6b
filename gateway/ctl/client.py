"""gx2ctl's side of the control protocol (:mod:`gateway.common.protocol`): one DEALER,
requests with an id and the time the client will wait, a deadline that is never
overrun, one safe retry, and the exit status of each outcome.
"""

from __future__ import annotations

import contextlib
import math
import time
import uuid
from typing import Any

import msgpack
import zmq

from gateway.common import curve, protocol
from gateway.common.endpoints import connectable
from gateway.common.protocol import MAX_REPLY_BYTES, Exit


class CtlError(Exception):
    """Ends the run: a one-line message and the exit status it gives."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(" ".join(message.split()) or "failed")
        self.status = status


class Client:
    """Requests over one DEALER; a request lost on the way is sent once more, with the
    same id, at half the timeout (the gateway answers a repeated id from its memory)."""

    def __init__(self, control: str, timeout: float,
                 keys: curve.ClientKeys | None = None) -> None:
        self.control = connectable(control, control)
        self.timeout = timeout
        self.context = zmq.Context()
        self.socket = self.context.socket(zmq.DEALER)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)
        self.secured = keys is not None
        if keys is not None:
            curve.connect_as(self.socket, keys)
        # The gateway remembers requests by (client identity, id): a fixed identity keeps
        # a retry sent over a new connection (after a network blip) the same request.
        self.socket.setsockopt(zmq.ROUTING_ID, b"gx2ctl-" + uuid.uuid4().hex.encode())
        try:
            self.socket.connect(self.control)
        except zmq.ZMQError as error:
            self.close()
            raise CtlError(f"cannot use control endpoint {self.control}: {error}",
                           Exit.USAGE) from None

    def close(self) -> None:
        self.socket.close(linger=0)
        self.context.term()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, op: str, *, extra_time: float = 0.0, **fields: Any) -> dict[str, Any]:
        """The ``result`` of one request; CtlError for an error reply or no reply.
        ``extra_time``: seconds the op is known to take on top of the usual timeout
        (a bias capture's sampling time)."""
        timeout = self.timeout + extra_time
        request_id = uuid.uuid4().hex
        payload = protocol.request(request_id, op, {**fields, "timeout": timeout})
        start = time.monotonic()
        deadline, resend_at = start + timeout, start + timeout / 2
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
                       f"{timeout:g} s (is gx2-gateway running"
                       f"{', and is this key allowed' if self.secured else ''}?)",
                       Exit.NO_ANSWER)

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
        raise CtlError("the gateway sent a malformed reply", Exit.NODE_FAILED)
    kind, message = error.get("kind"), error.get("message")
    text = message if isinstance(message, str) and message.strip() else f"{kind} error"
    raise CtlError(text, protocol.exit_for(kind))
