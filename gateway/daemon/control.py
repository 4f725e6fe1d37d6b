"""The control endpoint: a ZeroMQ ROUTER that runs each request as its own task, so a
slow request to one node never blocks a ping to another, and answers each exactly once.

Any message is answered or, if it cannot even carry an answer, dropped and counted:
never a crash. Requests are idempotent by (client, id) for a minute, so a client that
retries after a timeout gets the first run's answer instead of a second run.

A request that says how long its client waits (``timeout``) is answered before then,
whatever the node or the gateway's own background work is doing: an op still running
when its time is up is cancelled and answered as a node that did not answer in time.

A request still running when the gateway shuts down is answered too (``link``: the
gateway is shutting down) before the socket closes, so its client learns at once why
rather than waiting out its own timeout.

A client that gives up on its request (gx2ctl on Ctrl-C) sends ``cancel`` naming it:
the request is cancelled as its deadline would cancel it (each op leaves its node as it
would then, and says what stays: :attr:`~gateway.common.ops.Op.on_cancel`), or, past a
point where it cannot be stopped, goes on (:class:`~.errors.GoesOn`). Either way the
gateway logs it, and the cancel's answer says which.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections import OrderedDict
from typing import Any

import zmq
import zmq.asyncio

from gateway.common import curve, protocol
from gateway.common.ops import BY_NAME
from gateway.common.protocol import CANCEL, ErrorKind

from .errors import GoesOn, OpError
from .operations import Operations
from .requests import RequestBase, RequestError, answer_within, parse_request

log = logging.getLogger("gx2.control")
REMEMBER_SECONDS = 60.0
REMEMBER_MAX = 2048
IPC_MODE = 0o660
"""An ipc:// control socket: its owner and group may connect (gx2ctl users join the
gateway's group), nobody else."""
CLOSE_LINGER_MS = 100
"""At shutdown, how long the answers to the requests cut short may take to leave (a
client on this host or its network takes well under a millisecond): the process's exit
waits up to this long for them, within its 2 s."""
SHUTTING_DOWN = "cut short: the gateway is shutting down"
CANCEL_SHARE = 0.9
"""Of the time a cancel may take to be answered, the share it waits for the request it
cancels to wind down; then it says that it is winding down."""
Key = tuple[bytes, object]
"""A request as the gateway remembers it: (the client's identity, the request's id)."""


class ControlServer:
    def __init__(self, context: zmq.asyncio.Context, endpoint: str, ops: Operations,
                 server: curve.KeyPair | None = None) -> None:
        self.socket = context.socket(zmq.ROUTER)
        self.socket.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_REQUEST_BYTES + 1024)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.ROUTER_MANDATORY, 0)
        if server is not None:
            curve.serve(self.socket, server)
        self.socket.bind(endpoint)
        if endpoint.startswith("ipc://"):
            with contextlib.suppress(OSError):  # (an abstract @name has no file)
                os.chmod(endpoint[len("ipc://"):], IPC_MODE)
        self.endpoint = endpoint
        self.ops = ops
        self._seen: OrderedDict[Key, tuple[float, asyncio.Task[bytes]]] = OrderedDict()
        self._cancelled: dict[Key, tuple[bool, str] | None] = {}
        """Requests their client cancelled: whether each stopped and what it says (None
        while it winds down)."""
        self._answering: dict[asyncio.Task[None], tuple[list[bytes], RequestBase,
                                                        asyncio.Task[bytes]]] = {}
        """Each task waiting to answer a request: the request's envelope, the request,
        and the task running it."""
        self.requests = 0
        self.rejected = 0
        self.dropped = 0
        self.late = 0
        """Requests cut short by their deadline."""

    async def serve(self) -> None:
        while True:
            frames = await self.socket.recv_multipart(copy=True)
            self._accept(frames)

    def _accept(self, frames: list[bytes]) -> None:
        # ROUTER gives [identity, *envelope, payload]; REQ puts an empty frame first.
        if len(frames) < 2 or len(frames) > 3 or (len(frames) == 3 and frames[1] != b""):
            self.dropped += 1
            log.debug("dropped a control message of %d frames", len(frames))
            return
        envelope, payload = frames[:-1], frames[-1]
        self.requests += 1
        try:
            request = parse_request(payload)
        except RequestError as error:
            self.rejected += 1
            self._reply(envelope, protocol.error(error.request_id, ErrorKind.INVALID,
                                                 str(error)))
            return
        key = (envelope[0], request.id)
        self._forget_old()
        remembered = self._seen.get(key)
        if remembered is None:
            task = asyncio.get_running_loop().create_task(self._run(request, key),
                                                          name=_label(request))
            self._seen[key] = (time.monotonic(), task)
        else:
            task = remembered[1]
        answering = asyncio.get_running_loop().create_task(
            self._answer_when_done(envelope, task))
        self._answering[answering] = (envelope, request, task)
        answering.add_done_callback(self._answered)

    def _answered(self, answering: asyncio.Task[None]) -> None:
        self._answering.pop(answering, None)

    async def _answer_when_done(self, envelope: list[bytes], task: asyncio.Task[bytes]) -> None:
        self._reply(envelope, await asyncio.shield(task))

    def _reply(self, envelope: list[bytes], payload: bytes) -> None:
        try:
            self.socket.send_multipart([*envelope, payload], flags=zmq.NOBLOCK)
        except zmq.ZMQError as error:  # the client went away: nobody to answer
            log.debug("reply not sent: %s", error)

    def _forget_old(self) -> None:
        cutoff = time.monotonic() - REMEMBER_SECONDS
        while self._seen:
            when, task = next(iter(self._seen.values()))
            if (when < cutoff and task.done()) or len(self._seen) > REMEMBER_MAX:
                key, _ = self._seen.popitem(last=False)
                self._cancelled.pop(key, None)
            else:
                break

    async def _run(self, request: RequestBase, key: Key) -> bytes:
        """Run one validated request; always returns the one reply it gets."""
        limit = None if request.timeout is None else answer_within(request.timeout)
        try:
            async with asyncio.timeout(limit):
                if request.op == CANCEL:  # type: ignore[attr-defined]
                    return protocol.ok(request.id, await self._cancel(
                        key[0], request, None if limit is None else CANCEL_SHARE * limit))
                return protocol.ok(request.id, await self.ops.run(request))
        except asyncio.CancelledError:
            if key not in self._cancelled:
                raise  # (the gateway is shutting down)
            asyncio.current_task().uncancel()  # type: ignore[union-attr]  # (answered)
            text = _cancelled(request)
            log.info("%s", text)
            self._cancelled[key] = (True, text)
            return protocol.error(request.id, ErrorKind.CANCELLED, text)
        except GoesOn as error:
            if key in self._cancelled:
                log.warning("%s (cancelled by the client)", error)
                self._cancelled[key] = (False, str(error))
                return protocol.error(request.id, ErrorKind.CANCELLED, str(error))
            return protocol.error(request.id, error.kind, str(error))
        except TimeoutError:
            self.late += 1
            return protocol.error(request.id, ErrorKind.NODE, _too_late(request, limit))
        except OpError as error:
            return protocol.error(request.id, error.kind, str(error))
        except Exception as error:  # a bug: answer, log, and keep serving
            log.exception("request %r failed", request)
            return protocol.error(request.id, ErrorKind.INTERNAL,
                                  f"{type(error).__name__}: {error}")

    async def _cancel(self, identity: bytes, request: Any,
                      within: float | None) -> dict[str, Any]:
        """Cancel the client's own request ``request.request`` and wait for it to wind
        down (``within`` seconds at most): whether it stopped, and what it says."""
        key = (identity, request.request)
        remembered = self._seen.get(key)
        if remembered is None:
            return {"request": request.request, "cancelled": False,
                    "message": f"no request {request.request!r} of this client is running"}
        task = remembered[1]
        if not task.done() and key not in self._cancelled:
            self._cancelled[key] = None
            task.cancel()
        await asyncio.wait([task], timeout=within)
        outcome = self._cancelled.get(key, None)
        if not task.done():  # (switching BIT off, say, on a node slow to answer)
            return {"request": request.request, "cancelled": True,
                    "message": f"{task.get_name()} is being cancelled; the gateway logs "
                    "when it is"}
        if outcome is None:  # it had ended before the cancel came
            return {"request": request.request, "cancelled": False,
                    "message": f"{task.get_name()} had already ended (its result stands)"}
        stopped, text = outcome
        return {"request": request.request, "cancelled": stopped, "message": text}

    def close(self) -> None:
        """Answer every request still waiting for its answer (its own if it has just
        ended, else that the gateway is shutting down), cancel what still runs, and
        close the socket once those answers have left (CLOSE_LINGER_MS at most)."""
        for answering, (envelope, request, task) in list(self._answering.items()):
            if answering.done():
                continue  # (it has answered)
            answering.cancel()
            self._reply(envelope, task.result() if task.done() and not task.cancelled()
                        else _shutting_down(request))
        self._answering.clear()
        for _, task in self._seen.values():
            task.cancel()
        self.socket.close(linger=CLOSE_LINGER_MS)


def _label(request: Any) -> str:
    """The request in words (``bias capture on 76``)."""
    op = BY_NAME.get(request.op)
    return request.op if op is None else op.label(request)


def _cancelled(request: Any) -> str:
    """What a request cancelled by its client left: ``bias capture on 76 cancelled by
    the client; bias unchanged``."""
    op = BY_NAME.get(request.op)  # (None: a cancel, cancelled by another)
    on_cancel = "" if op is None else op.on_cancel
    return f"{_label(request)} cancelled by the client" + (
        f"; {on_cancel}" if on_cancel else "")


def _shutting_down(request: Any) -> bytes:
    return protocol.error(request.id, ErrorKind.LINK, f"{request.op}: {SHUTTING_DOWN}")


def _too_late(request: Any, limit: float | None) -> str:
    who = f"node {request.node}" if hasattr(request, "node") else "the nodes"
    return (f"{request.op}: {who} did not answer within the request's {request.timeout:g} s "
            f"(answered after {limit:.2f} s)")
