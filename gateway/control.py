"""The control endpoint: a ZeroMQ ROUTER that runs each request as its own task, so a
slow request to one node never blocks a ping to another, and answers each exactly once.

Any message is answered or, if it cannot even carry an answer, dropped and counted:
never a crash. Requests are idempotent by (client, id) for a minute, so a client that
retries after a timeout gets the first run's answer instead of a second run.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable
from typing import Any

import zmq
import zmq.asyncio

from . import curve, protocol
from .operations import Invalid, Operations, Refused
from .protocol import RequestError
from .scheduler import LinkDown, NodeError

log = logging.getLogger("gx2.control")
REMEMBER_SECONDS = 60.0
REMEMBER_MAX = 2048
IPC_MODE = 0o660
"""An ipc:// control socket: its owner and group may connect (gx2ctl users join the
gateway's group), nobody else."""


class ControlServer:
    def __init__(self, context: zmq.asyncio.Context, endpoint: str, ops: Operations,
                 status: Callable[[], dict[str, Any]],
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
        self.status = status
        self._seen: OrderedDict[tuple[bytes, object], tuple[float, asyncio.Task[bytes]]] = \
            OrderedDict()
        self._tasks: set[asyncio.Task[None]] = set()
        self.requests = 0
        self.rejected = 0
        self.dropped = 0

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
            request = protocol.parse_request(payload)
        except RequestError as error:
            self.rejected += 1
            self._reply(envelope, protocol.error(error.request_id, "invalid", str(error)))
            return
        key = (envelope[0], request.id)
        self._forget_old()
        remembered = self._seen.get(key)
        if remembered is None:
            task = asyncio.get_running_loop().create_task(self._run(request))
            self._seen[key] = (time.monotonic(), task)
        else:
            task = remembered[1]
        self._spawn(self._answer_when_done(envelope, task))

    def _spawn(self, coroutine: Awaitable[None]) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

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
                self._seen.popitem(last=False)
            else:
                break

    async def _run(self, request: protocol.Request) -> bytes:
        """Run one validated request; always returns the one reply it gets."""
        try:
            return protocol.ok(request.id, await self._dispatch(request))
        except Invalid as error:
            return protocol.error(request.id, "invalid", str(error))
        except Refused as error:
            return protocol.error(request.id, "refused", str(error))
        except NodeError as error:
            return protocol.error(request.id, "node", str(error))
        except LinkDown as error:
            return protocol.error(request.id, "link", str(error))
        except Exception as error:  # a bug: answer, log, and keep serving
            log.exception("request %r failed", request)
            return protocol.error(request.id, "internal", f"{type(error).__name__}: {error}")

    async def _dispatch(self, request: protocol.Request) -> dict[str, Any]:
        ops = self.ops
        match request:
            case protocol.PingRequest():
                return await ops.ping(request.nodes)
            case protocol.StatusRequest():
                return self.status()
            case protocol.StartRequest():
                return await ops.start(request.node, request.record)  # type: ignore[arg-type]
            case protocol.StopRequest():
                return await ops.stop(request.node)
            case protocol.PollRequest():
                return await ops.poll(request.node, request.record)  # type: ignore[arg-type]
            case protocol.EepromReadRequest():
                return await ops.eeprom_read(request.node, request.address)
            case protocol.EepromWriteRequest():
                return await ops.eeprom_write(request.node, request.address, request.value)
            case protocol.RateRequest():
                return await ops.rate(request.node, request.hz)
            case protocol.InfoRequest():
                return await ops.info(request.node)
        raise Invalid(f"op {request.op!r} is not served")  # pragma: no cover

    def close(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        for _, task in self._seen.values():
            task.cancel()
        self.socket.close()
