"""What control requests do: each operation as one async function over the scheduler.

Single steps (a poll) and multi-step ones (stop until silent, write then verify, arm a
stream until the node answers) read top to bottom here; the scheduler decides when
each packet goes out.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from aspp import commands
from aspp.commands import DOCUMENTED_EEPROM, EEPROM_DIVIDER, Command
from aspp.errors import AsppError
from aspp.frame import encode_ping
from aspp.records import lookup
from aspp.stop import GaveUp, SendStop, Stopped, StopPolicy

from .nodes import Delivery, NodeState
from .scheduler import REPLY_TIMEOUT, Answer, LinkDown, NodeError, Scheduler

log = logging.getLogger("gx2.ops")
ARM_BACKOFF = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
"""Between attempts to start a configured stream on a node that does not answer."""
STOP_MIN_SILENCE = 0.3
"""Silence that proves a stop, at the least: longer than a USB or scheduling stall, so a
stalled read is not taken for a stopped stream."""


class Invalid(Exception):
    """The request cannot be run as asked (gx2ctl exit 2)."""


class Refused(Exception):
    """The gateway's policy forbids the request (gx2ctl exit 1)."""


class Operations:
    def __init__(self, scheduler: Scheduler, nodes: dict[int, NodeState],
                 allow_eeprom_write: bool, allow_any_eeprom_address: bool = False) -> None:
        self.scheduler = scheduler
        self.nodes = nodes
        self.allow_eeprom_write = allow_eeprom_write
        self.allow_any_eeprom_address = allow_any_eeprom_address

    def node(self, address: int) -> NodeState:
        state = self.nodes.get(address)
        if state is None:
            raise Invalid(f"node {address} is not configured in this gateway")
        return state

    async def send(self, node: NodeState, command: Command, *,
                   wait_for_reply: bool = True) -> Answer:
        """One command to one node; the reply's Delivery is in ``answer.reply``. Without
        ``wait_for_reply`` it is done once the base station ACKs it."""
        timeout = REPLY_TIMEOUT + 2 * node.period
        expect = command.code if command.expects_reply and wait_for_reply else None
        return await self.scheduler.command(node.address, command.packet(node.address),
                                            expect, command.name, reply_timeout=timeout)

    async def ask(self, node: NodeState, command: Command) -> Delivery:
        answer = await self.send(node, command)
        assert isinstance(answer.reply, Delivery)
        return answer.reply

    # -- one per control op ----------------------------------------------------------------

    async def ping(self, addresses: list[int]) -> dict[str, Any]:
        results = await asyncio.gather(*(self.scheduler.ping(a, encode_ping(a))
                                         for a in addresses), return_exceptions=True)
        for result in results:  # a lost base station fails the request; a ping that
            if isinstance(result, BaseException) and not isinstance(result, NodeError):
                raise result    # got no answer byte at all is a node that did not answer
        return {"nodes": [{"node": a, "answered": result is True}
                          for a, result in zip(addresses, results, strict=True)]}

    async def start(self, address: int, record: str) -> dict[str, Any]:
        node = self.node(address)
        code = lookup(record).code
        answer = await self.send(node, commands.set_continuous(code))
        echoed = answer.reply.record["continuous_command"]
        if echoed != code:
            raise NodeError(f"node {address}: asked for 0x{code:02X}, it echoed 0x{echoed:02X}")
        node.streaming(lookup(code).name)
        return {"node": address, "record": node.record, "attempts": answer.attempts}

    async def stop(self, address: int) -> dict[str, Any]:
        """0xFA until the stream is silent (the long form in turn after a few tries)."""
        node = self.node(address)
        if node.stop_policy is not None:
            raise NodeError(f"node {address}: a stop is already running")
        policy = node.stop_policy = StopPolicy(node.period, min_silence=STOP_MIN_SILENCE)
        losses = self.scheduler.link_losses
        node.state = "stopping"
        try:
            while True:
                if self.scheduler.link_losses != losses or not self.scheduler.link_up:
                    raise LinkDown(f"node {address}: the base station was disconnected "
                                   "during the stop; the stream may still be running")
                action = policy.next_action(time.monotonic())
                if isinstance(action, SendStop):
                    try:  # the long form's reply is not awaited: silence decides
                        await self.send(node, action.command, wait_for_reply=False)
                        policy.sent(time.monotonic())
                    except NodeError as error:  # not even ACKed: the policy tries again
                        log.info("%s", error)
                elif isinstance(action, Stopped):
                    node.streaming(None)
                    log.info("node %d stopped after %d attempts", address, action.attempts)
                    return {"node": address, "attempts": action.attempts,
                            "elapsed": round(action.elapsed, 3)}
                elif isinstance(action, GaveUp):
                    node.state = "streaming" if node.record else "unknown"
                    raise NodeError(f"node {address}: still streaming after "
                                    f"{action.attempts} stop attempts")
                else:
                    await asyncio.sleep(max(0.0, min(0.05, action.deadline - time.monotonic())))
        finally:
            node.stop_policy = None

    async def poll(self, address: int, record: str) -> dict[str, Any]:
        node = self.node(address)
        return (await self.ask(node, commands.poll(record))).payload

    async def eeprom_read(self, address: int, word: int) -> dict[str, Any]:
        node = self.node(address)
        value = (await self.ask(node, commands.read_eeprom(word))).record["value"]
        return {"node": address, "address": word, "value": value}

    async def eeprom_write(self, address: int, word: int, value: int) -> dict[str, Any]:
        """Write, retry once if the reply shows the old word (the reference: the first
        write after power-up may fail), then read it back."""
        node = self.node(address)
        if not self.allow_eeprom_write:
            raise Refused("EEPROM writes are disabled on this gateway; to allow them set "
                          "control.allow_eeprom_write: true in its configuration and "
                          "restart it")
        if word not in DOCUMENTED_EEPROM and not self.allow_any_eeprom_address:
            known = ", ".join(f"0x{a:04X} ({what})" for a, what in DOCUMENTED_EEPROM.items())
            raise Refused(f"EEPROM 0x{word:04X} is not a word the reference documents "
                          f"({known}); to write it anyway set "
                          "control.allow_any_eeprom_address: true and restart the gateway")
        attempts = 0
        while True:
            attempts += 1
            stored = (await self.ask(node, commands.write_eeprom(word, value))).record["value"]
            if stored == value:
                break
            if attempts == 2:
                raise NodeError(f"node {address}: EEPROM 0x{word:04X} still holds {stored} "
                                f"after 2 writes of {value}")
        readback = (await self.ask(node, commands.read_eeprom(word))).record["value"]
        if readback != value:
            raise NodeError(f"node {address}: EEPROM 0x{word:04X} reads back {readback}, "
                            f"not {value}")
        if word == EEPROM_DIVIDER:
            node.divider = value
        return {"node": address, "address": word, "value": value, "attempts": attempts}

    async def rate(self, address: int, hz: float) -> dict[str, Any]:
        try:
            divider = commands.divider_for_rate(hz)
        except AsppError as error:
            raise Invalid(str(error)) from None
        await self.eeprom_write(address, EEPROM_DIVIDER, divider)
        return {"node": address, "hz": round(51200 / divider, 3), "divider": divider}

    async def info(self, address: int) -> dict[str, Any]:
        node = self.node(address)
        version = (await self.ask(node, commands.firmware_version())).record["version"]
        texts = []
        for selector in range(4):
            record = (await self.ask(node, commands.device_id(selector))).record
            if record["selector"] != selector:  # a late answer to an earlier request
                raise NodeError(f"node {address}: asked for identifier {selector}, "
                                f"got {record['selector']}")
            texts.append(record["text"])
        return {"node": address, "firmware": version, "model_number": texts[0],
                "serial_number": texts[1], "model_name": texts[2], "options": texts[3]}

    # -- background -------------------------------------------------------------------------

    async def arm(self, node: NodeState) -> None:
        """Start the node's configured stream, retrying with backoff for as long as the
        node does not answer; the other nodes never wait for it."""
        record = node.config.stream
        assert record is not None
        attempt = 0
        while True:
            node.state = "arming"  # ("unreachable" only while waiting out a backoff)
            try:
                divider = (await self.ask(node, commands.read_eeprom(EEPROM_DIVIDER)))
                if 170 <= divider.record["value"] <= 51200:
                    node.divider = divider.record["value"]
                await self.start(node.address, record)
                log.info("node %s streams %s at %.1f Hz", node.config.label, record,
                         51200 / node.divider)
                return
            except LinkDown:
                return  # re-armed when the base station is back
            except NodeError as error:
                node.state = "unreachable"
                delay = ARM_BACKOFF[min(attempt, len(ARM_BACKOFF) - 1)]
                log.warning("%s; retrying in %.1f s", error, delay)
                attempt += 1
                await asyncio.sleep(delay)
