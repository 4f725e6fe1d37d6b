"""gx2ctl's side of the control protocol (:mod:`gateway.common.protocol`): one DEALER,
requests with an id and the time the client will wait, a deadline that is never
overrun, one safe retry, the exit status of each outcome, and a cancel on Ctrl-C.
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
from gateway.common.protocol import CANCEL, MAX_REPLY_BYTES, Exit

INTERRUPTED = 130
"""The exit status of a run interrupted by Ctrl-C (128 + SIGINT), as a shell gives it."""
CANCEL_WAIT = 3.0
"""Seconds gx2ctl waits, after Ctrl-C, for the gateway to say what became of the
request (at most its --timeout): a request stops at its next safe point, well within."""


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

    def call(self, op: str, *, extra_time: float = 0.0, cancel: bool = False,
             **fields: Any) -> dict[str, Any]:
        """The ``result`` of one request; CtlError for an error reply or no reply.
        ``extra_time``: seconds the op is known to take on top of the usual timeout
        (a bias capture's sampling time). ``cancel``: Ctrl-C (KeyboardInterrupt)
        cancels the request on the gateway, and ends the run (CtlError, status 130)
        with one line saying what the gateway made of it."""
        timeout = self.timeout + extra_time
        request_id = uuid.uuid4().hex
        try:
            reply = self._exchange(request_id, op, fields, timeout)
        except KeyboardInterrupt:  # Ctrl-C: the gateway is told, and says what stays
            if not cancel:
                raise
            raise CtlError(f"interrupted: {self._cancel(request_id, op)}",
                           INTERRUPTED) from None
        if reply is not None:
            return _result(reply)
        raise CtlError(f"no answer from the gateway at {self.control} within "
                       f"{timeout:g} s (is gx2-gateway running"
                       f"{', and is this key allowed' if self.secured else ''}?)",
                       Exit.NO_ANSWER)

    def _cancel(self, request_id: str, op: str) -> str:
        """Ask the gateway to cancel our request; what it says became of it (stopped,
        and what stays; or what goes on), or what is not known."""
        wait = min(self.timeout, CANCEL_WAIT)
        reply = self._exchange(uuid.uuid4().hex, CANCEL, {"request": request_id}, wait)
        if reply is None:
            return (f"the gateway did not answer the cancel within {wait:g} s: the {op} "
                    "may go on (gx2ctl status shows the nodes)")
        try:
            result = _result(reply)
        except CtlError as error:  # (a gateway too old to take a cancel)
            return f"the gateway did not take the cancel ({error}): the {op} may go on"
        message = result.get("message")
        if not isinstance(message, str) or not message.strip():
            return f"the gateway sent a malformed answer to the cancel: the {op} may go on"
        return message

    def _exchange(self, request_id: str, op: str, fields: dict[str, Any],
                  timeout: float) -> dict[str, Any] | None:
        """Send one request and wait for its reply (None if none came in time)."""
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
                    return reply
        return None

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
