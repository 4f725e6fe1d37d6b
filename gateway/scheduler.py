"""Command scheduling on the shared base-station link: the one place commands are sent.

Rules, from the base station's behaviour:
* One packet (or raw ping) is in flight until its ACK or NACK (or ping answer) arrives,
  because those single bytes carry no address: only order tells whose they are.
* Once ACKed, a command waits for its reply by node and echo byte while the next
  command goes out, so a slow node never holds up the others. A node has at most one
  command awaiting a reply. (A reply is still ambiguous in two cases the wire cannot
  settle: a late reply to an attempt that timed out, and a poll of the record the node
  is streaming; both are answered by the first matching record.)
* A reply that arrives before its command's ACK completes the command, but the packet
  stays in flight until that ACK arrives (or its deadline passes), so the ACK is never
  credited to the next packet.
* Of the nodes with work, the one served least recently goes next: one node's backlog
  cannot starve another.
* A NACK, a missing ACK or a missing reply is retried with exponential backoff a
  bounded number of times; then the request fails with the reason.

The scheduler writes through a callback and learns of ACKs and replies from the
caller, which owns the port and the decoder; it only needs an asyncio loop for futures
and its own wake-up timer.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger("gx2.scheduler")

ACK_TIMEOUT = 0.6
"""Seconds to wait for ACK/NACK: a saturated base station queues it behind up to 4 KiB
of output (0.36 s at 115200 baud)."""
REPLY_TIMEOUT = 0.6
MAX_ATTEMPTS = 4
BACKOFF_FIRST = 0.05
BACKOFF_MAX = 1.0


@dataclass(frozen=True)
class Answer:
    """What a command came back with: the reply (None if only ACKed) and how many
    times the packet was sent."""

    reply: Any
    attempts: int


class NodeError(Exception):
    """A node did not answer, NACKed, or was not confirmed; the message says which."""


class LinkDown(Exception):
    """The base station is not connected."""


@dataclass(eq=False)
class _Request:
    node: int
    packet: bytes
    expect: int | None  # echo byte of the awaited reply; None: done when ACKed
    is_ping: bool
    what: str
    reply_timeout: float
    max_attempts: int
    future: asyncio.Future[Any]
    attempts: int = 0
    not_before: float = 0.0
    deadline: float = 0.0
    answered: bool = False
    """Its reply came before its ACK: the ACK or NACK still to come belongs to it."""
    reasons: list[str] = field(default_factory=list)

    @property
    def settled(self) -> bool:
        """Answered, failed, or abandoned by its caller: nothing more to do for it."""
        return self.answered or self.future.done()


@dataclass
class SchedulerStats:
    sent: int = 0
    acks: int = 0
    nacks: int = 0
    retries: int = 0
    failures: int = 0
    unexpected: int = 0
    """ACK, NACK or ping answers with nothing in flight (line noise, late answers)."""


class Scheduler:
    def __init__(self, write: Callable[[bytes], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._write = write
        self._clock = clock
        self._queues: dict[int, deque[_Request]] = {}
        self._served: dict[int, int] = {}  # node -> when it last sent (a send count)
        self._in_flight: _Request | None = None
        self._awaiting: dict[int, _Request] = {}
        self._timer: asyncio.TimerHandle | None = None
        self.link_up = False
        self.link_losses = 0
        """How many times the link went down: an operation that spans a loss knows it."""
        self.stats = SchedulerStats()

    # -- what the operations ask for -----------------------------------------------------

    async def command(self, node: int, packet: bytes, expect: int | None, what: str, *,
                      reply_timeout: float = REPLY_TIMEOUT,
                      attempts: int = MAX_ATTEMPTS) -> Answer:
        """Send a command packet; the answer holds what :meth:`on_reply` was given for
        the matching reply (None if ``expect`` is None: done at the ACK)."""
        request = _Request(node, packet, expect, False, what, reply_timeout, attempts,
                           asyncio.get_running_loop().create_future())
        return Answer(await self._submit(request), request.attempts)

    async def ping(self, node: int, packet: bytes) -> bool:
        """The raw wireless ping: True if the node answered (0x02), False for 0x21."""
        return bool(await self._submit(_Request(
            node, packet, None, True, "ping", 0.0, MAX_ATTEMPTS,
            asyncio.get_running_loop().create_future())))

    async def _submit(self, request: _Request) -> Any:
        if not self.link_up:
            raise LinkDown("the base station is not connected")
        self._queues.setdefault(request.node, deque()).append(request)
        self.service()
        return await request.future

    # -- what the reader reports -----------------------------------------------------------

    def on_ack(self) -> None:
        request = self._in_flight
        if request is None or request.is_ping:
            self.stats.unexpected += 1
            return
        self.stats.acks += 1
        self._in_flight = None
        if request.settled:  # answered already, or abandoned: the ACK just closes it
            self.service()
            return
        if request.expect is None:
            self._finish(request, None)
        else:
            request.deadline = self._clock() + request.reply_timeout
            self._awaiting[request.node] = request
        self.service()

    def on_nack(self) -> None:
        """0x21: a NACK of the packet in flight, or 'no answer' to a raw ping."""
        request = self._in_flight
        if request is None:
            self.stats.unexpected += 1
            return
        self._in_flight = None
        if request.settled:
            self.service()
            return
        if request.is_ping:
            self._finish(request, False)
        else:
            self.stats.nacks += 1
            self._retry(request, "NACK from the base station")
        self.service()

    def on_ping_ok(self) -> None:
        request = self._in_flight
        if request is not None and request.is_ping:
            self._in_flight = None
            self._finish(request, True)
            self.service()

    def on_reply(self, node: int, echo: int, answer: Any) -> None:
        """A reply record from ``node`` arrived; ``answer`` goes to whoever waits."""
        request = self._awaiting.get(node)
        if request is not None and request.expect == echo:
            del self._awaiting[node]
            self._finish(request, answer)
        elif (self._in_flight is not None and self._in_flight.node == node
              and self._in_flight.expect == echo and not self._in_flight.settled):
            request = self._in_flight  # answered before its ACK: keep it in flight so
            request.answered = True   # that ACK is not taken for the next packet's
            self._finish(request, answer)
        else:
            return
        self.service()

    def on_link_down(self) -> None:
        """Fail everything queued or in flight: no answer can come now."""
        self.link_up = False
        self.link_losses += 1
        requests = [r for q in self._queues.values() for r in q]
        requests += list(self._awaiting.values())
        if self._in_flight:
            requests.append(self._in_flight)
        self._queues.clear()
        self._awaiting.clear()
        self._in_flight = None
        for request in requests:
            if not request.future.done():
                request.future.set_exception(LinkDown("the base station was disconnected"))

    # -- the engine --------------------------------------------------------------------------

    def service(self) -> None:
        """Expire what timed out, send what may be sent, and set the next wake-up."""
        now = self._clock()
        request = self._in_flight
        if request is not None and now >= request.deadline:
            self._in_flight = None
            if not request.settled:
                self._retry(request, "no ACK from the base station")
        for node, request in list(self._awaiting.items()):
            if request.future.done():  # its caller gave up: free the node
                del self._awaiting[node]
            elif now >= request.deadline:
                del self._awaiting[node]
                self._retry(request, "no reply from the node")
        if self._in_flight is None and self.link_up:
            self._send_next(now)
        self._arm_timer(now)

    def _send_next(self, now: float) -> None:
        ready = []
        for node, queue in list(self._queues.items()):
            while queue and queue[0].future.done():  # abandoned by its caller
                queue.popleft()
            if not queue:
                del self._queues[node]
            elif node not in self._awaiting and queue[0].not_before <= now:
                ready.append(node)
        if not ready:
            return
        node = min(ready, key=lambda n: self._served.get(n, -1))
        head = self._queues[node].popleft()
        if not self._queues[node]:
            del self._queues[node]
        self._served[node] = self.stats.sent
        head.attempts += 1
        head.deadline = now + ACK_TIMEOUT
        self._in_flight = head
        self.stats.sent += 1
        try:
            self._write(head.packet)
        except OSError as error:
            log.warning("write failed: %s", error)

    def _retry(self, request: _Request, reason: str) -> None:
        request.reasons.append(reason)
        if request.future.done():
            return
        if request.attempts >= request.max_attempts:
            self.stats.failures += 1
            tries = f"{request.attempts} attempt{'s' if request.attempts > 1 else ''}"
            request.future.set_exception(NodeError(
                f"node {request.node}: {request.what}: {reason} ({tries})"))
            return
        self.stats.retries += 1
        request.not_before = self._clock() + min(
            BACKOFF_MAX, BACKOFF_FIRST * 2 ** (request.attempts - 1))
        self._queues.setdefault(request.node, deque()).appendleft(request)

    def _finish(self, request: _Request, answer: Any) -> None:
        if not request.future.done():
            request.future.set_result(answer)

    def _arm_timer(self, now: float) -> None:
        times = [r.deadline for r in self._awaiting.values()]
        if self._in_flight is not None:
            times.append(self._in_flight.deadline)
        elif self.link_up:
            times += [q[0].not_before for q in self._queues.values() if q]
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if times:
            loop = asyncio.get_running_loop()
            self._timer = loop.call_later(max(0.0, min(times) - now), self.service)
