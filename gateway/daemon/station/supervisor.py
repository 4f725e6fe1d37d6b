"""The supervisor: it keeps every node doing what it should.

What a node should do is its ``desired`` stream (:class:`~gateway.daemon.station.nodes.Node`):
the configured ``stream:`` until an operator's ``start`` or ``stop`` replaces it, for as
long as the gateway runs. The supervisor pursues it, in the background and at the
scheduler's background priority, whenever the node may have stopped doing it:

* the base station comes back (every node);
* a node reboots, seen three ways: its discovery packet; its timer going back (a
  reboot whose discovery packet was lost, when it came back streaming something else);
  its stream falling silent for ten sample periods and at least 1 s;
* a node streams on its own (EEPROM auto-start, or a stream started before the
  gateway): two unsolicited records of one streamable record make it a stream, the
  node's rate read from their timer step; an operator's stop is then enforced again;
* an operator's start or stop did not take (the node did not answer): the intent
  stands, and it is tried again with backoff until it takes or is replaced; a node
  kept stopped that comes back streaming is stopped at once.

A node that does not answer is retried with backoff (0.5 s up to 30 s) and never holds
up another. An out-of-range node whose stream comes back by itself is taken as it is.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from aspp import commands
from aspp.commands import EEPROM_DIVIDER
from aspp.frame import encode_ping
from aspp.records import Record, lookup
from aspp.stop import GaveUp, NoAnswer, Probe, SendStop, Stopped, StopPolicy
from aspp.timing import TICKS_PER_CLOCK, TIMER_MODULUS

from ..errors import LinkDown, NodeError
from .nodes import OFF, Node, State
from .scheduler import Priority, Scheduler

log = logging.getLogger("gx2.supervisor")
BACKOFF = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
"""Between attempts to make a node that does not answer do what it should."""
STOP_MIN_SILENCE = 0.3
"""Silence that proves a stop, at the least: longer than a USB or scheduling stall, so a
stalled read is not taken for a stopped stream."""
STOP_POLL = 0.05
"""How often a stop looks at its policy while it waits for silence."""
PROBE_PINGS = 3
"""Wireless pings a stop sends to learn whether the node is within reach: a ping, like
any packet, can be lost on the way while the node is there."""
WATCH_MIN_SLEEP = 0.25
"""The least the stream watcher sleeps; also how long a stall's backlog is given to be
read before any stream is judged silent."""
WATCH_MAX_SLEEP = 1.0
"""The most it sleeps: no stream armed meanwhile can fall silent sooner (SILENCE_MIN)."""


@dataclass
class Held:
    """A node kept quiet for a command: the record it streamed before (None: none),
    and the record started again afterwards (None: none, or not yet)."""

    streamed: str | None
    restored: str | None = None


class Supervisor:
    def __init__(self, scheduler: Scheduler, nodes: dict[int, Node],
                 passive: bool = False) -> None:
        self.scheduler = scheduler
        self.nodes = nodes
        self.passive = passive
        """Watch, never act (a replay: nothing may be sent)."""
        self.link_up = False
        self.closed = False
        """The gateway is shutting down: nothing more is started for any node."""
        self._pursuits: dict[int, asyncio.Task[None]] = {}
        self._stops: dict[int, StopPolicy] = {}
        self._unsolicited: dict[int, tuple[str, int | None]] = {}
        """Per node, the last streamable record nobody asked for: (name, timer)."""

    # -- what happens to the link and the nodes --------------------------------------------

    def link_changed(self, up: bool) -> None:
        self.link_up = up
        for node in self.nodes.values():
            if up:
                node.link_back()
                self._pursue(node)
            else:
                self._abandon(node)
                node.link_lost()

    def discovery(self, node: Node) -> None:
        """The node announced a power-up: whatever it streamed is gone."""
        log.warning("node %s rebooted (discovery packet)", node.label)
        node.rebooted()
        self._pursue(node)

    def after_record(self, node: Node, record: Record) -> None:
        """One record of ``node``, already counted and published, that is not simply the
        next record of the stream a streaming node is known to stream (the reader does
        not ask about those)."""
        spec = record.spec
        if node.take_timer_reset():
            log.warning("node %s rebooted (its timer went back)", node.label)
            if spec.name != node.desired:
                node.rebooted_quietly()
                self._pursue(node)
                return
        if node.state is State.BUSY:
            return  # (its replies and any stragglers of its stream: not a stream now)
        policy = self._stops.get(node.address)
        if policy is not None:  # a stop runs (stopping, or still probing): its evidence
            now = time.monotonic()
            if spec.streamable:
                policy.packet_seen(now)
            if spec.code == 0xC4 and record.values[0] == 0:
                policy.stop_confirmed(now)
            return
        if (node.state is State.UNREACHABLE and node.desired == OFF and spec.streamable
                and not self.scheduler.expects(node.address, spec.code)):
            # back within reach, streaming what an operator stopped: stopped now, not at
            # the next retry of the stop (up to the last BACKOFF away)
            node.streaming(spec.name)
            log.info("node %s is back, streaming %s: stopping it again", node.label,
                     spec.name)
            self._pursue(node)
            return
        if not spec.streamable or spec.name == node.record:
            return
        if node.state is State.UNREACHABLE and spec.name == node.desired:
            # out of range, not rebooted: its stream came back while a retry waits
            self._abandon(node)
            node.streaming(spec.name)
            log.info("node %s: its %s stream came back by itself", node.label, spec.name)
            return
        if node.state is not State.ARMING and not self.scheduler.expects(node.address,
                                                                         spec.code):
            self._unsolicited_record(node, spec.name, record.timer)

    def _unsolicited_record(self, node: Node, name: str, timer: int | None) -> None:
        """A streamable record nobody asked for: the second in a row makes a stream."""
        previous = self._unsolicited.get(node.address)
        self._unsolicited[node.address] = (name, timer)
        if previous is None or previous[0] != name:
            return
        divider = None
        if timer is not None and previous[1] is not None:
            divider = round(((timer - previous[1]) % TIMER_MODULUS) / TICKS_PER_CLOCK)
        del self._unsolicited[node.address]
        node.streaming(name, divider)
        log.info("node %s streams %s on its own, at %.1f Hz", node.label, name,
                 1 / node.period)
        if node.desired is not None and node.desired != name:
            self._pursue(node)

    async def watch_streams(self) -> None:
        """A stream that fell silent (a reboot whose discovery packet was lost, or the
        node out of range) is counted and pursued again. A timer, not a tick: it sleeps
        until the earliest moment a stream could fall silent."""
        while True:
            now = time.monotonic()
            due = min((at for node in self.nodes.values()
                       if (at := node.silent_at()) is not None), default=now + WATCH_MAX_SLEEP)
            delay = min(max(due - now, WATCH_MIN_SLEEP), WATCH_MAX_SLEEP)
            await asyncio.sleep(delay)
            woke = time.monotonic()
            # after a stall of this process the bytes it has not read yet may hold the
            # records: judge no stream until they have had their chance
            if woke - now > delay + WATCH_MIN_SLEEP or not self.link_up:
                continue
            for node in self.nodes.values():
                if node.fell_silent(woke):
                    log.warning("node %s: its %s stream fell silent", node.label,
                                node.record)
                    if node.desired not in (None, OFF):
                        self._pursue(node)

    # -- the operator's intent ---------------------------------------------------------------

    async def start(self, node: Node, record: str) -> dict[str, object]:
        """Stream ``record`` from now on, through reboots, until the next start or stop."""
        node.want(record)
        await self._halt(node)
        try:
            attempts = await self._start(node, record, Priority.OPERATOR)
        except BaseException:
            self._pursue(node)  # the intent stands: it is pursued in the background
            raise
        return {"node": node.address, "record": node.record, "attempts": attempts}

    async def stop(self, node: Node) -> dict[str, object]:
        """0xFA until the stream is silent; the node is kept stopped through reboots."""
        node.want(OFF)
        await self._halt(node)
        try:
            return await self._stop(node, Priority.OPERATOR)
        except BaseException:
            self._pursue(node)
            raise

    @asynccontextmanager
    async def quiet(self, node: Node) -> AsyncIterator[Held]:
        """The node without its stream, for a command that needs it quiet (a bias
        capture, a self-test): a stream it runs is stopped first, and what it should
        stream is started again afterwards (in the background if the command failed).

        Only if the node is still the command's when it ends: the base station lost or
        the node rebooted meanwhile is what the node's state says from then on, and the
        supervisor already pursues it (when the link is back, or since the reboot).
        Overwriting that with "polled" showed a node whose link was down as polled and
        OK (issue 19)."""
        await self._halt(node)
        held = Held(node.record)
        if held.streamed is not None:
            try:
                await self._stop(node, Priority.OPERATOR)
            except BaseException:
                self._pursue(node)  # (a node that did not answer is retried, as ever)
                raise
        node.busy()
        try:
            yield held
        except BaseException:
            if self._give_back(node) and not self.closed:
                self._pursuits[node.address] = asyncio.get_running_loop().create_task(
                    self._restore(node, held.streamed))
            raise
        if self._give_back(node) and not self.closed:
            held.restored = await self._restore(node, held.streamed)

    def _give_back(self, node: Node) -> bool:
        """After a quiet command: settle the node and say so if nothing else happened
        to it meanwhile (it is still BUSY); otherwise leave it as it is."""
        if node.state is not State.BUSY:
            return False
        node.settled()
        return True

    async def _restore(self, node: Node, streamed: str | None) -> str | None:
        """Start again what the node should stream after a quiet command: its desired
        stream, or the one it ran on its own if nothing is desired. The record started,
        or None."""
        record = streamed if node.desired is None else node.desired
        if record is None or record == OFF:
            return None
        try:
            await self._start(node, record, Priority.OPERATOR)
        except LinkDown as error:  # armed again when the base station is back
            log.info("node %s: %s stream not started again: %s", node.label, record, error)
            return None
        except NodeError as error:
            log.warning("node %s: %s stream not started again: %s", node.label, record,
                        error)
            self._pursue(node)
            return None
        return record

    # -- a reload's nodes ------------------------------------------------------------------

    def adopt(self, node: Node) -> None:
        """A node a reload added to :attr:`nodes`: armed as at start, now if the base
        station is up (else when it comes up, with every node)."""
        if self.link_up:
            node.link_back()
            self._pursue(node)
        else:
            node.link_lost()

    def rearm(self, node: Node) -> None:
        """A node whose configured stream a reload changed: it pursues the new one."""
        self._pursue(node)

    async def retire(self, node: Node) -> str | None:
        """A node a reload removed: its stream, if it runs one, stopped as ``stop`` does
        (at operator priority), and the node never pursued again. Why it was not
        confirmed stopped, or None."""
        node.want(OFF)
        await self._halt(node)
        self._unsolicited.pop(node.address, None)
        if node.record is None:
            return None  # (nothing streams, as far as the gateway knows)
        try:
            await self._stop(node, Priority.OPERATOR)
        except (NodeError, LinkDown) as error:
            return str(error)
        finally:
            self._abandon(node)  # (whatever its records started meanwhile)
        return None

    # -- pursuing what a node should do ---------------------------------------------------

    def _pursue(self, node: Node) -> None:
        """Make ``node`` do what it should, in the background (replacing whatever was
        being done for it)."""
        old = self._pursuits.pop(node.address, None)
        if old is not None:
            old.cancel()
        if not self.link_up or self.passive or self.closed:
            return
        desired = node.desired
        # a node kept stopped that streams nothing is left as it is, unless it is in
        # trouble (it did not answer): then whether it streams is not known, and the
        # stop is pursued (by pings alone until it answers)
        if desired is None or (desired == OFF and node.record is None
                               and node.trouble is None):
            node.settled()
            return
        self._pursuits[node.address] = asyncio.get_running_loop().create_task(
            self._pursuit(node, old))

    def _abandon(self, node: Node) -> None:
        task = self._pursuits.pop(node.address, None)
        if task is not None:
            task.cancel()

    async def _halt(self, node: Node) -> None:
        """Stop the background pursuit of ``node``, and wait until it has let go."""
        task = self._pursuits.pop(node.address, None)
        if task is not None:
            task.cancel()
            await asyncio.wait([task])

    async def _pursuit(self, node: Node, previous: asyncio.Task[None] | None) -> None:
        if previous is not None:
            await asyncio.wait([previous])  # (its stop, if it ran one, has ended)
        attempt = 0
        while True:
            desired = node.desired
            try:
                if desired == OFF:
                    await self._stop(node, Priority.BACKGROUND)
                elif desired is not None:
                    await self._arm(node, desired)
                return
            except LinkDown:
                return  # pursued again when the base station is back
            except NodeError as error:
                if node.state is not State.STREAMING:
                    node.unreachable()
                delay = BACKOFF[min(attempt, len(BACKOFF) - 1)]
                log.warning("%s; retrying in %.1f s", error, delay)
                attempt += 1
                await asyncio.sleep(delay)

    async def _arm(self, node: Node, record: str) -> None:
        """Read the node's rate, then start its stream."""
        node.arming()
        answer = await self.scheduler.ask(node, commands.read_eeprom(EEPROM_DIVIDER),
                                          priority=Priority.BACKGROUND,
                                          what="reading its data-rate divider (EEPROM "
                                               "0xFCA2) to arm its stream")
        node.divider_read(answer.record["value"])  # type: ignore[arg-type]
        await self._start(node, record, Priority.BACKGROUND)
        log.info("node %s streams %s at %.1f Hz", node.label, record, 1 / node.period)

    async def _start(self, node: Node, record: str, priority: Priority) -> int:
        """C4 C1 29 <record>, its echo checked; returns the attempts it took."""
        code = lookup(record).code
        answer = await self.scheduler.send(node, commands.set_continuous(code),
                                           priority=priority)
        echoed = answer.reply.record["continuous_command"]
        if echoed != code:
            raise NodeError(f"node {node.address}: asked for 0x{code:02X}, it echoed "
                            f"0x{echoed:02X}")
        node.streaming(lookup(code).name)
        return answer.attempts

    # A stop is confirmed only by evidence that the node could hear it (issue 21:
    # "stop 95" of a node out of range answered "stopped", exit 0, and the node then
    # showed polled and OK). 0xFA has no reply, and the base station's ACK says only
    # that it went on the air, so silence is all a stop has; but a node out of range is
    # silent too. So the policy runs with check_reach (aspp.stop): silence proves the
    # stop once the node has been heard since the stop began, by its stream's records
    # (a node whose stream was arriving when the stop went out is within reach) or the
    # long form's reply; otherwise a wireless ping must be answered (the base station
    # says 02 only if the node answered). A node not known to stream (unreachable,
    # silent, polled, being armed) is pinged before any 0xFA: one that does not answer
    # is sent no command it cannot hear, and its background retries are pings alone.
    # Not heard: NoAnswer, "not confirmed: no answer", exit 1; the node is marked
    # unreachable, the operator's intent (off) stands, and the pursuit stops the node
    # when it answers or its stream comes back (after_record).
    async def _stop(self, node: Node, priority: Priority) -> dict[str, object]:
        """0xFA until the stream is silent (the long form in turn after a few tries),
        confirmed only if the node was heard (its records, or an answered ping)."""
        if node.address in self._stops:
            raise NodeError(f"node {node.address}: a stop is already running")
        policy = self._stops[node.address] = StopPolicy(
            node.period, min_silence=STOP_MIN_SILENCE, check_reach=True,
            streaming=node.state is State.STREAMING)
        losses = self.scheduler.link_losses
        try:
            while True:
                if self.scheduler.link_losses != losses or not self.scheduler.link_up:
                    raise LinkDown(f"node {node.address}: the base station was "
                                   "disconnected during the stop; the stream may still "
                                   "be running")
                action = policy.next_action(time.monotonic())
                if isinstance(action, SendStop):
                    if action.attempt == 1:
                        node.stopping()
                    try:  # the long form's reply is not awaited: silence decides
                        await self.scheduler.send(node, action.command, priority=priority,
                                                  wait_for_reply=False)
                        policy.sent(time.monotonic())
                    except NodeError as error:  # not even ACKed: the policy tries again
                        log.info("%s", error)
                elif isinstance(action, Probe):
                    if await self._answers_ping(node, priority):
                        policy.answered(time.monotonic())
                    else:
                        policy.unanswered(time.monotonic())
                elif isinstance(action, Stopped):
                    node.polled()
                    log.info("node %s stopped after %d attempt%s", node.label,
                             action.attempts, "" if action.attempts == 1 else "s")
                    return {"node": node.address, "attempts": action.attempts,
                            "elapsed": round(action.elapsed, 3)}
                elif isinstance(action, NoAnswer):
                    node.unreachable()
                    raise NodeError(self._no_answer(node, action))
                elif isinstance(action, GaveUp):
                    raise NodeError(f"node {node.address}: still streaming after "
                                    f"{action.attempts} stop attempts")
                else:
                    await asyncio.sleep(max(0.0, min(STOP_POLL,
                                                     action.deadline - time.monotonic())))
        except BaseException:
            node.stop_failed()
            raise
        finally:
            del self._stops[node.address]

    async def _answers_ping(self, node: Node, priority: Priority) -> bool:
        """Whether the node answers one of PROBE_PINGS wireless pings."""
        for _ in range(PROBE_PINGS):
            try:
                if await self.scheduler.ping(node.address, encode_ping(node.address),
                                             priority):
                    return True
            except NodeError as error:  # no answer byte from the base station at all
                log.info("%s", error)
        return False

    @staticmethod
    def _no_answer(node: Node, result: NoAnswer) -> str:
        sent = ("no stop sent" if result.attempts == 0 else
                f"silent after {result.attempts} stop{'s' if result.attempts > 1 else ''}")
        return (f"node {node.address}: stop not confirmed: no answer ({sent}; "
                f"{PROBE_PINGS} pings unanswered: out of range?); the gateway stops it "
                "when it is back")

    # -- shutdown -----------------------------------------------------------------------------

    async def stop_all_streams(self) -> None:
        """One 0xFA to every streaming node, best effort (shutdown.stop_streams)."""
        streaming = [n for n in self.nodes.values() if n.record]
        await asyncio.gather(*(self.scheduler.send(n, commands.stop_continuous(),
                                                   wait_for_reply=False)
                               for n in streaming), return_exceptions=True)

    def close(self) -> None:
        self.closed = True
        for task in self._pursuits.values():
            task.cancel()
        self._pursuits.clear()
