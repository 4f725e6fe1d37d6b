"""Command scheduling on the shared base-station link: the one place commands are sent.

Rules, from the base station's behaviour:
* One packet (or raw ping) is in flight until its ACK or NACK (or ping answer) arrives,
  because those single bytes carry no address: only order tells whose they are.
* Once ACKed, a command waits for its reply by node and echo byte while the next
  command goes out, so a slow node never holds up the others. A node has at most one
  command awaiting a reply. (A reply is still ambiguous in two cases the wire cannot
  settle: a late reply to an attempt that timed out, and a poll of the record the node
  is streaming; both are answered by the first matching record.) A raw ping needs no
  reply slot: the base station answers it, so it never waits behind a node's command.
* A reply that arrives before its command's ACK completes the command, but the packet
  stays in flight until that ACK arrives (or its deadline passes), so the ACK is never
  credited to the next packet.
* An operator's request goes ahead of the gateway's own background work (arming a
  stream, retrying an unreachable node): in a node's queue, and across nodes. A
  background command that is awaiting its reply finishes that attempt, and its retry
  then queues behind the operator's request, so background work holds an operator
  back by one attempt at most.
* Of the nodes with work of the same priority, the one served least recently goes
  next: one node's backlog cannot starve another.
* A NACK, a missing ACK or a missing reply is retried with exponential backoff a
  bounded number of times; then the request fails with the reason. A request whose
  caller gave up (its deadline passed, it was cancelled) is dropped at once.

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
from enum import IntEnum
from typing import TYPE_CHECKING, Any, Protocol

from aspp.commands import Command

from ..errors import LinkDown, NodeError

if TYPE_CHECKING:
    from .nodes import Delivery

log = logging.getLogger("gx2.scheduler")

ACK_TIMEOUT = 0.6
"""Seconds to wait for ACK/NACK: a saturated base station queues it behind up to 4 KiB
of output (0.36 s at 115200 baud)."""
REPLY_TIMEOUT = 0.6
MAX_ATTEMPTS = 4
BACKOFF_FIRST = 0.05
BACKOFF_MAX = 1.0


class Priority(IntEnum):
    OPERATOR = 0
    """A control request: someone is waiting for it."""
    BACKGROUND = 1
    """The gateway's own work: arming streams, recovering nodes."""


class Addressee(Protocol):
    """What the scheduler needs of a node: where to send, how often it samples."""

    @property
    def address(self) -> int: ...

    @property
    def period(self) -> float: ...


@dataclass(frozen=True)
class Answer:
    """What a command came back with: the reply (None if only ACKed) and how many
    times the packet was sent."""

    reply: Any
    attempts: int


@dataclass(eq=False)
class _Pending:
    """One command packet or raw ping, from submission to its answer."""

    node: int
    packet: bytes
    expect: int | None  # echo byte of the awaited reply; None: done when ACKed
    is_ping: bool
    what: str
    priority: Priority
    reply_timeout: float
    max_attempts: int
    future: asyncio.Future[Any]
    resend_unanswered: bool = True
    """False: a command the base station took (ACKed) and the node did not answer fails
    at once, never sent twice (a bias capture); a NACK is still sent again."""
    on_sent: Callable[[], None] | None = None
    """Called when the packet is first written to the port: from then on the node may
    act on it, whatever becomes of the request."""
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

    @property
    def queue(self) -> tuple[int, bool]:
        """Commands queue by node; a node's pings apart, as they need no reply slot."""
        return self.node, self.is_ping


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
                 clock: Callable[[], float] = time.monotonic, station: str = "") -> None:
        """``station``: the base station's name, which a request that fails because it
        is down names (with several, the user must know which one to look at)."""
        self._write = write
        self._station = f"base station {station}" if station else "the base station"
        self._clock = clock
        self._queues: dict[tuple[int, bool], deque[_Pending]] = {}
        self._served: dict[tuple[int, bool], int] = {}  # queue -> when it last sent
        self._in_flight: _Pending | None = None
        self._awaiting: dict[int, _Pending] = {}
        self._timer: asyncio.TimerHandle | None = None
        self.link_up = False
        self.link_losses = 0
        """How many times the link went down: an operation that spans a loss knows it."""
        self.stats = SchedulerStats()

    # -- what the operations ask for -----------------------------------------------------

    async def command(self, node: int, packet: bytes, expect: int | None, what: str, *,
                      reply_timeout: float = REPLY_TIMEOUT, attempts: int = MAX_ATTEMPTS,
                      priority: Priority = Priority.OPERATOR,
                      resend_unanswered: bool = True,
                      on_sent: Callable[[], None] | None = None) -> Answer:
        """Send a command packet; the answer holds what :meth:`on_reply` was given for
        the matching reply (None if ``expect`` is None: done at the ACK)."""
        pending = _Pending(node, packet, expect, False, what, priority, reply_timeout,
                           attempts, asyncio.get_running_loop().create_future(),
                           resend_unanswered, on_sent)
        return Answer(await self._submit(pending), pending.attempts)

    async def send(self, node: Addressee, command: Command, *,
                   priority: Priority = Priority.OPERATOR, wait_for_reply: bool = True,
                   what: str | None = None, takes: float = 0.0,
                   resend_unanswered: bool = True,
                   on_sent: Callable[[], None] | None = None) -> Answer:
        """One GX2 command to one node; the reply's :class:`Delivery` is in
        ``answer.reply``. Without ``wait_for_reply`` it is done once the base station
        ACKs it. The reply may trail a record of the node's own stream by two periods,
        and ``takes`` seconds more for a command that works that long (a bias capture).
        ``what`` names the command in an error (default: the record's name);
        ``on_sent`` is called when it is first written (:class:`_Pending`)."""
        expect = command.code if command.expects_reply and wait_for_reply else None
        return await self.command(node.address, command.packet(node.address), expect,
                                  what or command.name, priority=priority,
                                  reply_timeout=REPLY_TIMEOUT + 2 * node.period + takes,
                                  resend_unanswered=resend_unanswered, on_sent=on_sent)

    async def ask(self, node: Addressee, command: Command, *,
                  priority: Priority = Priority.OPERATOR, what: str | None = None) -> Delivery:
        """One command and its reply (raises NodeError or LinkDown without one)."""
        return (await self.send(node, command, priority=priority,  # type: ignore[no-any-return]
                                what=what)).reply

    async def ping(self, node: int, packet: bytes,
                   priority: Priority = Priority.OPERATOR) -> bool:
        """The raw wireless ping: True if the node answered (0x02), False for 0x21."""
        return bool(await self._submit(_Pending(
            node, packet, None, True, "ping", priority, 0.0, MAX_ATTEMPTS,
            asyncio.get_running_loop().create_future())))

    def expects(self, node: int, echo: int) -> bool:
        """Whether a command sent to ``node`` is waiting for a reply with this echo."""
        pending = self._awaiting.get(node)
        if pending is not None and pending.expect == echo:
            return True
        flying = self._in_flight
        return flying is not None and flying.node == node and flying.expect == echo

    async def _submit(self, pending: _Pending) -> Any:
        if not self.link_up:
            raise LinkDown(f"{self._station} is down (not connected)")
        self._enqueue(pending)
        pending.future.add_done_callback(lambda _: self._abandoned(pending))
        self.service()
        return await pending.future

    def _abandoned(self, pending: _Pending) -> None:
        """A command awaiting its reply whose caller gave up frees its node now, not at
        its reply deadline (a bias capture's is seconds away): the commands queued
        behind it wait on nothing else."""
        if self._awaiting.get(pending.node) is pending:
            self.service()

    def _enqueue(self, pending: _Pending, retry: bool = False) -> None:
        """Behind the requests of its own priority or higher (a retry: ahead of those
        of its own priority), ahead of lower ones."""
        queue = self._queues.setdefault(pending.queue, deque())
        at = next((i for i, other in enumerate(queue) if other.priority > pending.priority
                   or (retry and other.priority == pending.priority)), len(queue))
        queue.insert(at, pending)

    # -- what the reader reports -----------------------------------------------------------

    def on_ack(self) -> None:
        pending = self._in_flight
        if pending is None or pending.is_ping:
            self.stats.unexpected += 1
            return
        self.stats.acks += 1
        self._in_flight = None
        if pending.settled:  # answered already, or abandoned: the ACK just closes it
            self.service()
            return
        if pending.expect is None:
            self._finish(pending, None)
        else:
            pending.deadline = self._clock() + pending.reply_timeout
            self._awaiting[pending.node] = pending
        self.service()

    def on_nack(self) -> None:
        """0x21: a NACK of the packet in flight, or 'no answer' to a raw ping."""
        pending = self._in_flight
        if pending is None:
            self.stats.unexpected += 1
            return
        self._in_flight = None
        if pending.settled:
            self.service()
            return
        if pending.is_ping:
            self._finish(pending, False)
        else:
            self.stats.nacks += 1
            self._retry(pending, "NACK from the base station")
        self.service()

    def on_ping_ok(self) -> None:
        pending = self._in_flight
        if pending is not None and pending.is_ping:
            self._in_flight = None
            self._finish(pending, True)
            self.service()

    def on_reply(self, node: int, echo: int, answer: Any) -> None:
        """A reply record from ``node`` arrived; ``answer`` goes to whoever waits."""
        pending = self._awaiting.get(node)
        if pending is not None and pending.expect == echo:
            del self._awaiting[node]
            self._finish(pending, answer)
        elif (self._in_flight is not None and self._in_flight.node == node
              and self._in_flight.expect == echo and not self._in_flight.settled):
            pending = self._in_flight  # answered before its ACK: keep it in flight so
            pending.answered = True   # that ACK is not taken for the next packet's
            self._finish(pending, answer)
        else:
            return
        self.service()

    def on_link_down(self) -> None:
        """Fail everything queued or in flight: no answer can come now."""
        self.link_up = False
        self.link_losses += 1
        every = [p for q in self._queues.values() for p in q]
        every += list(self._awaiting.values())
        if self._in_flight:
            every.append(self._in_flight)
        self._queues.clear()
        self._awaiting.clear()
        self._in_flight = None
        for pending in every:
            if not pending.future.done():
                pending.future.set_exception(LinkDown(f"{self._station} was disconnected"))

    # -- the engine --------------------------------------------------------------------------

    def service(self) -> None:
        """Expire what timed out, send what may be sent, and set the next wake-up."""
        now = self._clock()
        pending = self._in_flight
        if pending is not None and now >= pending.deadline:
            self._in_flight = None
            if not pending.settled:
                self._retry(pending, "no ACK from the base station")
        for node, pending in list(self._awaiting.items()):
            if pending.future.done():  # its caller gave up: free the node
                del self._awaiting[node]
            elif now >= pending.deadline:
                del self._awaiting[node]
                self._retry(pending, "no reply from the node",
                            resend=pending.resend_unanswered)
        if self._in_flight is None and self.link_up:
            self._send_next(now)
        self._arm_timer(now)

    def _send_next(self, now: float) -> None:
        best: tuple[int, int] | None = None
        chosen: tuple[int, bool] | None = None
        for key, queue in list(self._queues.items()):
            while queue and queue[0].future.done():  # abandoned by its caller
                queue.popleft()
            if not queue:
                del self._queues[key]
                continue
            ready = self._ready_at(queue[0])
            if ready is None or ready > now:
                continue
            head = queue[0]
            rank = (head.priority, self._served.get(key, -1))
            if best is None or rank < best:
                best, chosen = rank, key
        if chosen is None:
            return
        queue = self._queues[chosen]
        head = queue.popleft()
        if not queue:
            del self._queues[chosen]
        self._served[chosen] = self.stats.sent
        head.attempts += 1
        head.deadline = now + ACK_TIMEOUT
        self._in_flight = head
        self.stats.sent += 1
        try:
            self._write(head.packet)
        except OSError as error:
            log.warning("write failed: %s", error)
            return
        if head.on_sent is not None:
            head.on_sent()
            head.on_sent = None

    # The one rule for both sending (_send_next) and waking (_arm_timer). Issue 19: the
    # timer took the not_before of a head held back behind its node's awaited reply
    # (0.0 for a new request), so it fired at once, again and again, until the reply
    # came: 120,007 service() calls in 1 s, and 93% of a core for the whole of a 5 s
    # bias capture with a poll of the same node queued behind it (bench/capture_cpu.py).
    def _ready_at(self, head: _Pending) -> float | None:
        """When a queue's head may be sent; None while its node awaits a reply, as what
        ends that wait wakes the scheduler itself: the reply (:meth:`on_reply`), its
        deadline (the timer) or its caller giving up (:meth:`_abandoned`)."""
        if not head.is_ping and head.node in self._awaiting:
            return None
        return head.not_before

    def _retry(self, pending: _Pending, reason: str, resend: bool = True) -> None:
        pending.reasons.append(reason)
        if pending.future.done():
            return
        if pending.attempts >= pending.max_attempts or not resend:
            self.stats.failures += 1
            tries = f"{pending.attempts} attempt{'s' if pending.attempts > 1 else ''}"
            pending.future.set_exception(NodeError(
                f"node {pending.node}: {pending.what}: {reason} ({tries})"))
            return
        self.stats.retries += 1
        pending.not_before = self._clock() + min(
            BACKOFF_MAX, BACKOFF_FIRST * 2 ** (pending.attempts - 1))
        self._enqueue(pending, retry=True)

    def _finish(self, pending: _Pending, answer: Any) -> None:
        if not pending.future.done():
            pending.future.set_result(answer)

    def _arm_timer(self, now: float) -> None:
        times = [p.deadline for p in self._awaiting.values()]
        if self._in_flight is not None:
            times.append(self._in_flight.deadline)
        elif self.link_up:
            times += [ready for q in self._queues.values()
                      if q and (ready := self._ready_at(q[0])) is not None]
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if times:
            loop = asyncio.get_running_loop()
            self._timer = loop.call_later(max(0.0, min(times) - now), self.service)
